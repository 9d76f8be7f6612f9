"""The mesh node tree: the mesh counterpart of the SDF node tree (:mod:`ipm.sdf.nodes`).

Nodes are immutable data with named, bounded parameters, registered by type name:

* primitives (no children), centered at the origin, Y up, sizes are full extents like the SDF
  nodes: ``box``, ``cylinder``, ``cone``, ``uv_sphere``, ``revolve`` (a polyline ``(r_i, y_i)``
  revolved about Y and closed on the axis), ``extrude`` (a polygon ``(x_i, z_i)`` in the XZ plane
  extruded along Y);
* transforms (one child): ``translate``, ``rotate`` (the SDF node's angle / tilt / azimuth),
  ``scale`` (uniform), ``scale3``;
* ``merge`` (one or more children): their meshes side by side (concatenation, no CSG).

Files use the SDF trees' nested JSON form, ``{"node": "translate", "name": ..., "params": {...},
"children": [...]}`` (sized nodes also carry ``"size"``), optionally wrapped as
``{"generator": "meshtree", "tree": {...}}``. Parameters are flat and named ``<label>.<param>``
(label: the node's ``name`` or ``n<preorder index>_<type>``); all are continuous. The number of
segments of round primitives is the level of detail (:class:`MeshLod`), not a parameter.

Jacobians. Transforms are affine and act on every vertex alike, so their Jacobian with respect to
the vertices is block diagonal with one 3x3 block. :meth:`MeshTree.jacobian` uses that: each
primitive's own ``(V, 3, k)`` Jacobian and each ancestor transform's columns
``dA/dtheta v + db/dtheta`` are multiplied once by the composed 3x3 linear part of the transforms
above them (a batched 3x3 product per vertex) and written into their column block, instead of
pushing dense tangents for all parameters through every node. Tests compare it with ``jacfwd`` and
finite differences.
"""

from __future__ import annotations

import json
import math
from abc import ABC, abstractmethod
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, fields
from pathlib import Path
from typing import ClassVar

import numpy as np
import torch
from torch.func import jacfwd, vmap

from ipm.generators import _meshkit as mk
from ipm.generators._meshkit import smul, ssub
from ipm.generators.base import Generator, register_generator
from ipm.params import Param, ParamSpec, Value, dataclass_from
from ipm.types import TriMesh

LEN = (1e-3, 20.0)
POS = (-20.0, 20.0)
ANGLE = (-360.0, 360.0)


def P(name: str, default: float, lo: float = LEN[0], hi: float = LEN[1], doc: str = "") -> Param:
    return Param(name, default, lo, hi, "float", doc)


@dataclass(frozen=True)
class MeshLod:
    """Level of detail of round primitives: ``segments`` around their axis, ``rings`` from pole to
    pole of a sphere."""

    segments: int = 32
    rings: int = 16

    def __post_init__(self) -> None:
        for f in fields(self):
            v = getattr(self, f.name)
            if not isinstance(v, (int, np.integer)) or isinstance(v, bool) or v < 3:
                raise ValueError(f"lod {f.name}: expected an integer >= 3, got {v!r}")


LODS = {"low": MeshLod(16, 8), "medium": MeshLod(), "high": MeshLod(64, 32)}


def resolve_lod(lod) -> MeshLod:
    """A :class:`MeshLod` from None (medium), a name (low, medium, high), a dict or a MeshLod."""
    if lod is None:
        return LODS["medium"]
    if isinstance(lod, MeshLod):
        return lod
    if isinstance(lod, str):
        if lod not in LODS:
            raise ValueError(f"lod: expected one of {', '.join(LODS)}, got {lod!r}")
        return LODS[lod]
    if isinstance(lod, Mapping):
        return dataclass_from(MeshLod, lod, "lod")
    raise ValueError(f"lod: expected None, a name, a dict or a MeshLod, got {type(lod).__name__}")


# ----------------------------------------------------------------------------------------------
# Nodes and their registry
# ----------------------------------------------------------------------------------------------

MESH_NODES: dict[str, type[MeshNode]] = {}


def register_mesh_node(cls: type[MeshNode]) -> type[MeshNode]:
    """Class decorator: add a mesh node type to the registry under ``cls.type_name``."""
    if not getattr(cls, "type_name", None):
        raise ValueError(f"{cls.__name__}: mesh node types need a type_name")
    if cls.type_name in MESH_NODES and MESH_NODES[cls.type_name] is not cls:
        raise ValueError(f"mesh node type {cls.type_name!r} is registered twice")
    MESH_NODES[cls.type_name] = cls
    return cls


def mesh_node_type(name: str) -> type[MeshNode]:
    """A mesh node type by name; ``ValueError`` lists the known names."""
    try:
        return MESH_NODES[name]
    except KeyError:
        raise ValueError(f"unknown mesh node type {name!r}; known: {', '.join(sorted(MESH_NODES))}") from None


@dataclass(frozen=True, eq=False)
class MeshNode:
    """A mesh node instance: its type's parameter values (in declaration order), children, the size
    of sized nodes (number of polyline / polygon points) and an optional name (its label)."""

    values: tuple = ()
    children: tuple[MeshNode, ...] = ()
    size: int | None = None
    name: str | None = None

    type_name: ClassVar[str] = ""
    arity: ClassVar[int | None] = 0          # None: one or more children
    params: ClassVar[tuple[Param, ...]] = ()
    sized: ClassVar[bool] = False
    default_size: ClassVar[int | None] = None
    min_size: ClassVar[int] = 1

    @classmethod
    def param_defs_for(cls, size: int | None) -> tuple[Param, ...]:
        return cls.params

    def param_defs(self) -> tuple[Param, ...]:
        return type(self).param_defs_for(self.size)

    @classmethod
    def make(cls, *args, children: Sequence[MeshNode] = (), size: int | None = None,
             name: str | None = None, **kwargs) -> MeshNode:
        """Build an instance from positional then keyword values (defaults for the rest)."""
        size = cls._size(size)
        defs = cls.param_defs_for(size)
        if len(args) > len(defs):
            raise ValueError(f"{cls.type_name}: expected at most {len(defs)} values "
                             f"({', '.join(p.name for p in defs)}), got {len(args)}")
        given = {p.name: v for p, v in zip(defs, args)}
        for k, v in kwargs.items():
            if k in given:
                raise ValueError(f"{cls.type_name}: value for {k!r} given twice")
            given[k] = v
        return cls.from_values(given, children=children, size=size, name=name)

    @classmethod
    def _size(cls, size) -> int | None:
        if not cls.sized:
            if size is not None:
                raise ValueError(f"{cls.type_name}: takes no size, got {size}")
            return None
        size = cls.default_size if size is None else size
        if not isinstance(size, (int, np.integer)) or isinstance(size, bool) or size < cls.min_size:
            raise ValueError(f"{cls.type_name}: expected size >= {cls.min_size}, got {size!r}")
        return int(size)

    @classmethod
    def from_values(cls, given: Mapping[str, object], *, children: Sequence[MeshNode] = (),
                    size: int | None = None, name: str | None = None) -> MeshNode:
        """Build an instance from named values, checking names, bounds and children."""
        size = cls._size(size)
        kids = tuple(children)
        if cls.arity is None and len(kids) < 1:
            raise ValueError(f"{cls.type_name}: expected at least 1 child, got 0")
        if cls.arity is not None and len(kids) != cls.arity:
            raise ValueError(f"{cls.type_name}: expected {cls.arity} child{'ren' if cls.arity != 1 else ''}, "
                             f"got {len(kids)}")
        defs = cls.param_defs_for(size)
        values = ParamSpec(defs).validate(given)
        node = cls(values=tuple(values[p.name] for p in defs), children=kids, size=size, name=name)
        node.check()
        return node

    def check(self) -> None:
        """Extra validation of the stored values (raise ``ValueError``)."""

    def replace_values(self, values: tuple, children: tuple) -> MeshNode:
        return type(self).from_values(dict(zip((p.name for p in self.param_defs()), values)),
                                      children=children, size=self.size, name=self.name)


class Primitive(MeshNode, ABC):
    """A leaf: vertices from its own parameters ``th: (k,)`` and a fixed face list."""

    arity = 0

    @abstractmethod
    def verts(self, th: torch.Tensor, lod: MeshLod) -> torch.Tensor:
        """Vertices ``(V, 3)`` in the node's frame."""

    @abstractmethod
    def faces(self, lod: MeshLod) -> np.ndarray:
        """Faces ``(F, 3) int64`` NumPy array (outward, counter-clockwise seen from outside)."""

    def n_verts(self, lod: MeshLod) -> int:
        return int(self.faces(lod).max()) + 1

    #: True when the vertices are a linear function of the parameters (no constant term): then the
    #: Jacobian is the vertices of the unit parameter vectors, one batched evaluation.
    linear: ClassVar[bool] = False

    def jacobian(self, th: torch.Tensor, lod: MeshLod) -> torch.Tensor:
        """``d verts / d th``: ``(V, 3, k)``."""
        if self.linear:
            eye = torch.eye(th.shape[0], dtype=th.dtype, device=th.device)
            return vmap(lambda e: self.verts(e, lod), out_dims=2)(eye)
        return jacfwd(lambda t: self.verts(t, lod))(th)


class Transform(MeshNode, ABC):
    """One child, whose vertices are mapped by an affine map ``v -> A v + b``."""

    arity = 1

    @abstractmethod
    def affine(self, th: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        """``A: (3, 3)``, ``b: (3,)`` from the node's parameters ``th: (k,)``."""

    def affine_jacobian(self, th: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        """``dA/dth: (3, 3, k)``, ``db/dth: (3, k)``."""
        return jacfwd(self.affine)(th)


# -- primitives --------------------------------------------------------------------------------

def _revolved(r: torch.Tensor, y: torch.Tensor, bottom, top, lod: MeshLod) -> torch.Tensor:
    return mk.revolve(r, y, lod.segments, bottom=bottom, top=top)


@register_mesh_node
@dataclass(frozen=True, eq=False)
class Box(Primitive):
    """Axis-aligned box with full edge lengths ``size_x/y/z`` (8 vertices)."""

    linear = True
    type_name = "box"
    params = (P("size_x", 1.0), P("size_y", 1.0), P("size_z", 1.0))

    def verts(self, th, lod):
        h = smul(th, 0.5)[None]
        return mk.box_verts(-h, h)

    def faces(self, lod):
        return mk.repeat_faces_np(None, 8, 1, 2, 4)

    def n_verts(self, lod):
        return 8


@register_mesh_node
@dataclass(frozen=True, eq=False)
class Cylinder(Primitive):
    """Capped cylinder along Y: ``radius``, full ``height`` (two rings and two cap centers)."""

    linear = True
    type_name = "cylinder"
    params = (P("radius", 0.5), P("height", 1.0))

    def verts(self, th, lod):
        r, h = th.split(1)
        y = smul(h, 0.5)
        return _revolved(torch.cat([r, r]), torch.cat([-y, y]), -y, y, lod)

    def faces(self, lod):
        return mk.loft_faces_np(2, lod.segments, "pole", "pole")

    def n_verts(self, lod):
        return 2 * lod.segments + 2


@register_mesh_node
@dataclass(frozen=True, eq=False)
class Cone(Primitive):
    """Capped cone along Y: ``radius_bottom`` at y = -h/2, ``radius_top`` at +h/2 (small, not zero,
    for a pointed cone: the mesh keeps its top ring)."""

    linear = True
    type_name = "cone"
    params = (P("radius_bottom", 0.5), P("radius_top", 0.1), P("height", 1.0))

    def verts(self, th, lod):
        r0, r1, h = th.split(1)
        y = smul(h, 0.5)
        return _revolved(torch.cat([r0, r1]), torch.cat([-y, y]), -y, y, lod)

    def faces(self, lod):
        return mk.loft_faces_np(2, lod.segments, "pole", "pole")

    def n_verts(self, lod):
        return 2 * lod.segments + 2


def _meridian(rings: int) -> np.ndarray:
    """``(2, rings - 1)``: sin and -cos of the interior latitudes of a half turn."""
    a = np.arange(1, rings) * (math.pi / rings)
    return np.stack([np.sin(a), -np.cos(a)])


@register_mesh_node
@dataclass(frozen=True, eq=False)
class UVSphere(Primitive):
    """UV sphere of ``radius``: ``rings - 1`` latitude rings of ``segments`` vertices and two poles."""

    linear = True
    type_name = "uv_sphere"
    params = (P("radius", 0.5),)

    def verts(self, th, lod):
        s, c = mk.const(_meridian, lod.rings, like=th)
        return _revolved(th * s, th * c, -th, th, lod)

    def faces(self, lod):
        return mk.loft_faces_np(lod.rings - 1, lod.segments, "pole", "pole")

    def n_verts(self, lod):
        return (lod.rings - 1) * lod.segments + 2


@register_mesh_node
@dataclass(frozen=True, eq=False)
class Revolve(Primitive):
    """A polyline ``(r0, y0) .. (r{k-1}, y{k-1})`` revolved about Y and closed by the axis points
    ``(0, y0)`` and ``(0, y{k-1})``. The outside is on the right going from the first point to the
    last with the axis on the left, so ``y{k-1} > y0`` (checked)."""

    linear = True
    type_name = "revolve"
    sized = True
    default_size = 4
    min_size = 1

    @classmethod
    def param_defs_for(cls, size):
        k = cls.default_size if size is None else size
        out = []
        for i in range(k):
            t = i / max(k - 1, 1)
            out += [P(f"r{i}", round(0.5 * math.sin(math.pi * (0.15 + 0.7 * t)), 6), 1e-3, 20.0),
                    P(f"y{i}", round(t - 0.5, 6), *POS)]
        return tuple(out)

    @classmethod
    def size_from_names(cls, names):
        return sum(1 for n in names if n.startswith("r") and n[1:].isdigit()) or None

    def check(self):
        ys = self.values[1::2]
        if not ys[-1] > ys[0]:
            raise ValueError(f"revolve: expected the profile to end above its start (y{len(ys) - 1} > y0), "
                             f"got y0 = {ys[0]}, y{len(ys) - 1} = {ys[-1]}")

    def verts(self, th, lod):
        pts = th.reshape(-1, 2)
        r, y = pts[:, 0], pts[:, 1]
        return _revolved(r, y, y[:1], y[-1:], lod)

    def faces(self, lod):
        return mk.loft_faces_np(self.size, lod.segments, "pole", "pole")

    def n_verts(self, lod):
        return self.size * lod.segments + 2


@register_mesh_node
@dataclass(frozen=True, eq=False)
class Extrude(Primitive):
    """A polygon ``(x0, z0) .. (x{k-1}, z{k-1})`` in the XZ plane extruded along Y by ``height``
    (centered). The caps are fans from the vertex mean, so the polygon must be star-shaped around it
    (convex polygons are); either orientation is accepted (fixed when the node is built)."""

    linear = True
    type_name = "extrude"
    sized = True
    default_size = 6
    min_size = 3

    @classmethod
    def param_defs_for(cls, size):
        k = cls.default_size if size is None else size
        out = [P("height", 0.5)]
        for i in range(k):
            a = 2.0 * math.pi * i / k
            out += [P(f"x{i}", round(0.5 * math.cos(a), 6), *POS),
                    P(f"z{i}", round(-0.5 * math.sin(a), 6), *POS)]
        return tuple(out)

    @classmethod
    def size_from_names(cls, names):
        return sum(1 for n in names if n.startswith("x") and n[1:].isdigit()) or None

    def _reversed(self) -> bool:
        # counter-clockwise about +Y means a positive area in the (z, x) plane
        x, z = np.array(self.values[1::2]), np.array(self.values[2::2])
        return float(np.sum(z * np.roll(x, -1) - np.roll(z, -1) * x)) < 0.0

    def check(self):
        x, z = np.array(self.values[1::2]), np.array(self.values[2::2])
        if abs(float(np.sum(z * np.roll(x, -1) - np.roll(z, -1) * x))) < 1e-12:
            raise ValueError("extrude: expected a polygon with a non-zero area")

    def verts(self, th, lod):
        h = smul(th[:1], 0.5)
        pts = th[1:].reshape(-1, 2)
        if self._reversed():
            pts = torch.flip(pts, (0,))
        k = pts.shape[0]
        center = smul(pts.sum(0), 1.0 / k)                                     # (2,)
        ring_lo = torch.stack([pts[:, 0], (-h).expand(k), pts[:, 1]], -1)
        ring_hi = torch.stack([pts[:, 0], h.expand(k), pts[:, 1]], -1)
        c_lo = torch.cat([center[:1], -h, center[1:]])[None]
        c_hi = torch.cat([center[:1], h, center[1:]])[None]
        return torch.cat([c_lo, ring_lo, ring_hi, c_hi])

    def faces(self, lod):
        return mk.loft_faces_np(2, self.size, "pole", "pole")

    def n_verts(self, lod):
        return 2 * self.size + 2


# -- transforms --------------------------------------------------------------------------------

@register_mesh_node
@dataclass(frozen=True, eq=False)
class Translate(Transform):
    """Move the child by ``(x, y, z)``."""

    type_name = "translate"
    params = (P("x", 0.0, *POS), P("y", 0.0, *POS), P("z", 0.0, *POS))

    def affine(self, th):
        return mk.const(np.eye, 3, like=th), th

    def affine_jacobian(self, th):
        return mk.const(np.zeros, (3, 3, 3), like=th), mk.const(np.eye, 3, like=th)


def rotation(angle: torch.Tensor, tilt: torch.Tensor, azimuth: torch.Tensor) -> torch.Tensor:
    """Rodrigues rotation ``(3, 3)`` by ``angle`` degrees about +Y tilted by ``tilt`` degrees towards
    the XZ direction at ``azimuth`` degrees (each ``(1,)``): the SDF ``rotate`` node's convention."""
    a, t, z = smul(angle, math.pi / 180), smul(tilt, math.pi / 180), smul(azimuth, math.pi / 180)
    st = torch.sin(t)
    x, y, w = st * torch.cos(z), torch.cos(t), st * torch.sin(z)
    c, s = torch.cos(a), torch.sin(a)
    C = ssub(1.0, c)
    return torch.cat([c + x * x * C, x * y * C - w * s, x * w * C + y * s,
                      y * x * C + w * s, c + y * y * C, y * w * C - x * s,
                      w * x * C - y * s, w * y * C + x * s, c + w * w * C]).reshape(3, 3)


def _cross(k: torch.Tensor) -> torch.Tensor:
    """``[k]x``: the ``(3, 3)`` matrix of ``v -> k x v`` for ``k: (3,)``."""
    x, y, w = k.split(1)
    zero = torch.zeros_like(x)
    return torch.cat([zero, -w, y, w, zero, -x, -y, x, zero]).reshape(3, 3)


@register_mesh_node
@dataclass(frozen=True, eq=False)
class Rotate(Transform):
    """Rotate the child by ``angle`` degrees about +Y tilted by ``tilt`` towards ``azimuth`` (the
    SDF ``rotate`` node's parameters and convention)."""

    type_name = "rotate"
    params = (P("angle", 0.0, *ANGLE), P("tilt", 0.0, *ANGLE), P("azimuth", 0.0, *ANGLE))

    def affine(self, th):
        a, t, z = th.split(1)
        return rotation(a, t, z), torch.zeros_like(th)

    def affine_jacobian(self, th):
        """Rodrigues ``R = c I + s [k]x + (1 - c) k k^T`` differentiated in closed form."""
        d = math.pi / 180
        a, t, z = (smul(x, d) for x in th.split(1))
        st, ct, sz, cz = torch.sin(t), torch.cos(t), torch.sin(z), torch.cos(z)
        c, s = torch.cos(a), torch.sin(a)
        C = ssub(1.0, c)
        zero = torch.zeros_like(st)
        k = torch.cat([st * cz, ct, st * sz])
        k_t = torch.cat([ct * cz, -st, ct * sz])
        k_z = torch.cat([-(st * sz), zero, st * cz])
        eye = mk.const(np.eye, 3, like=th)
        kk = k[:, None] * k[None, :]
        d_angle = -s * eye + c * _cross(k) + s * kk

        def d_axis(dk):
            return s * _cross(dk) + C * (dk[:, None] * k[None, :] + k[:, None] * dk[None, :])

        dA = smul(torch.stack([d_angle, d_axis(k_t), d_axis(k_z)], -1), d)
        return dA, mk.const(np.zeros, (3, 3), like=th)


@register_mesh_node
@dataclass(frozen=True, eq=False)
class Scale(Transform):
    """Uniform scale by ``factor`` about the origin."""

    type_name = "scale"
    params = (P("factor", 1.0, 1e-3, 100.0),)

    def affine(self, th):
        return th * mk.const(np.eye, 3, like=th), torch.zeros_like(th).expand(3)

    def affine_jacobian(self, th):
        return mk.const(np.eye, 3, like=th)[..., None], mk.const(np.zeros, (3, 1), like=th)


def _diag_basis() -> np.ndarray:
    """``(3, 3, 3)``: d diag(s) / d s_k."""
    out = np.zeros((3, 3, 3))
    out[[0, 1, 2], [0, 1, 2], [0, 1, 2]] = 1.0
    return out


@register_mesh_node
@dataclass(frozen=True, eq=False)
class Scale3(Transform):
    """Non-uniform scale by ``(sx, sy, sz)`` about the origin."""

    type_name = "scale3"
    params = (P("sx", 1.0, 1e-3, 100.0), P("sy", 1.0, 1e-3, 100.0), P("sz", 1.0, 1e-3, 100.0))

    def affine(self, th):
        return torch.diag_embed(th), torch.zeros_like(th)

    def affine_jacobian(self, th):
        return mk.const(_diag_basis, like=th), mk.const(np.zeros, (3, 3), like=th)


@register_mesh_node
@dataclass(frozen=True, eq=False)
class Merge(MeshNode):
    """The children's meshes together (concatenation; overlapping parts are not fused)."""

    type_name = "merge"
    arity = None


# ----------------------------------------------------------------------------------------------
# Trees
# ----------------------------------------------------------------------------------------------

def _preorder(node: MeshNode, parent: int = -1):
    stack = [(node, parent)]
    index = 0
    while stack:
        n, par = stack.pop()
        yield index, n, par
        me = index
        index += 1
        for c in reversed(n.children):
            stack.append((c, me))


def node_label(node: MeshNode, index: int) -> str:
    return node.name or f"n{index}_{node.type_name}"


@dataclass(frozen=True)
class _Prim:
    node: Primitive
    label: str
    sl: slice
    chain: tuple[int, ...]          # indices into MeshTree._transforms, outermost first


class MeshTree:
    """A validated tree of mesh nodes with a flat, continuous parameter vector.

    ``spec`` lists every parameter as ``<label>.<param>``; ``theta`` holds them in pre-order.
    """

    def __init__(self, root: MeshNode):
        if not isinstance(root, MeshNode):
            raise ValueError(f"expected a mesh node as the tree root, got {type(root).__name__}")
        self.root = root
        params, labels, offsets, off = [], [], [], 0
        order = list(_preorder(root))
        for i, node, _ in order:
            label = node_label(node, i)
            labels.append(label)
            offsets.append(off)
            for p, v in zip(node.param_defs(), node.values):
                params.append(Param(f"{label}.{p.name}", v, p.lo, p.hi, p.kind, p.doc))
                off += 1
        if len(set(labels)) != len(labels):
            dup = sorted({x for x in labels if labels.count(x) > 1})
            raise ValueError(f"mesh tree: node names must be unique, got {', '.join(dup)} more than once")
        self.spec = ParamSpec(tuple(params))
        self.labels = labels
        self._topologies: dict[MeshLod, mk.Topology] = {}
        self._linear_jacobians: dict[tuple, torch.Tensor] = {}
        self._transforms: list[tuple[Transform, slice]] = []
        self._prims: list[_Prim] = []
        chain_of: dict[int, tuple[int, ...]] = {-1: ()}
        for i, node, par in order:
            sl = slice(offsets[i], offsets[i] + len(node.param_defs()))
            chain = chain_of[par]
            if isinstance(node, Transform):
                self._transforms.append((node, sl))
                chain = chain + (len(self._transforms) - 1,)
            elif isinstance(node, Primitive):
                self._prims.append(_Prim(node, labels[i], sl, chain))
            chain_of[i] = chain

    def __repr__(self) -> str:
        return f"MeshTree({len(self._prims)} primitives, {len(self.spec)} parameters)"

    @property
    def n_params(self) -> int:
        return len(self.spec)

    def theta(self, dtype=torch.float64, device=None) -> torch.Tensor:
        """The stored values, ``(n,)``."""
        return torch.tensor([float(p.default) for p in self.spec.params], dtype=dtype, device=device)

    def with_values(self, values: Mapping[str, object]) -> MeshTree:
        """A new tree with some parameters replaced by name (validated)."""
        full = self.spec.validate(values)
        it = iter(full[p.name] for p in self.spec.params)

        def rebuild(node):
            vals = tuple(next(it) for _ in node.param_defs())
            kids = tuple(rebuild(c) for c in node.children)
            return node.replace_values(vals, kids)

        return MeshTree(rebuild(self.root))

    # -- geometry ------------------------------------------------------------------------------
    def _check_theta(self, theta: torch.Tensor) -> None:
        if theta.ndim != 1 or theta.shape[0] != self.n_params:
            raise ValueError(f"theta: expected shape ({self.n_params},), got {tuple(theta.shape)}")

    def _affines(self, theta: torch.Tensor) -> list[tuple[torch.Tensor, torch.Tensor]]:
        return [t.affine(theta[sl]) for t, sl in self._transforms]

    def _composed(self, aff, chain):
        """The composed affine map of a chain of transforms (outermost first)."""
        A, b = aff[chain[0]]
        for t in chain[1:]:
            At, bt = aff[t]
            A, b = A @ At, A @ bt + b
        return A, b

    def mesh(self, theta: torch.Tensor, lod=None) -> TriMesh:
        """The merged mesh for ``theta: (n,) float``; one face group per primitive (its label)."""
        self._check_theta(theta)
        L = resolve_lod(lod)
        aff = self._affines(theta)
        verts = []
        for pr in self._prims:
            v = pr.node.verts(theta[pr.sl], L)
            if pr.chain:
                A, b = self._composed(aff, pr.chain)
                v = v @ A.T + b                                     # one batched 3x3 map per primitive
            verts.append(v)
        return self._topology(L).mesh(verts)

    def _topology(self, L: MeshLod) -> mk.Topology:
        if L not in self._topologies:
            self._topologies[L] = mk.Topology.build([pr.node.faces(L) for pr in self._prims],
                                                    [pr.node.n_verts(L) for pr in self._prims],
                                                    [pr.label for pr in self._prims])
        return self._topologies[L]

    def _primitive_jacobian(self, index: int, pr: _Prim, theta: torch.Tensor, L: MeshLod) -> torch.Tensor:
        """A primitive's own ``(V, 3, k)`` Jacobian; constant (cached) for linear primitives."""
        if not pr.node.linear or mk._traced(theta):
            return pr.node.jacobian(theta[pr.sl], L)
        key = (index, L, theta.dtype, theta.device)
        if key not in self._linear_jacobians:
            self._linear_jacobians[key] = pr.node.jacobian(theta[pr.sl].detach(), L)
        return self._linear_jacobians[key]

    def jacobian(self, theta: torch.Tensor, lod=None) -> torch.Tensor:
        """``d verts / d theta``, ``(3V, n)`` (rows x0, y0, z0, x1, ...), from per-vertex 3x3 blocks.

        For a primitive under transforms ``T_1 .. T_m`` (outermost first) with linear parts ``A_i``:
        its own columns are ``A_1 .. A_m J_prim`` and the columns of ``T_i`` are
        ``A_1 .. A_{i-1} (dA_i v_i + db_i)`` with ``v_i`` the vertices in ``T_i``'s child frame.
        """
        self._check_theta(theta)
        L = resolve_lod(lod)
        aff = self._affines(theta)
        daff = [t.affine_jacobian(theta[sl]) for t, sl in self._transforms]
        n_rows = self._topology(L).n_verts
        J = theta.new_zeros((n_rows, 3, self.n_params))
        row = 0
        for pi, pr in enumerate(self._prims):
            v = pr.node.verts(theta[pr.sl], L)
            n = v.shape[0]
            # vertices in every transform's child frame, innermost first, and the linear parts of the
            # transforms outside each one, outermost first
            frames = [v]
            for t in reversed(pr.chain):
                A, b = aff[t]
                frames.append(frames[-1] @ A.T + b)
            outside = [None]
            for t in pr.chain:
                A = aff[t][0]
                outside.append(A if outside[-1] is None else outside[-1] @ A)
            for i, t in enumerate(pr.chain):
                dA, db = daff[t]
                if outside[i] is not None:            # fold the 3x3 block into the tiny derivatives
                    dA = torch.einsum("ab,bck->ack", outside[i], dA)
                    db = outside[i] @ db
                v_child = frames[len(pr.chain) - 1 - i]
                J[row:row + n, :, self._transforms[t][1]] = torch.einsum("abk,vb->vak", dA, v_child) + db
            J_p = self._primitive_jacobian(pi, pr, theta, L)                        # (V, 3, k)
            if outside[-1] is not None:
                J_p = torch.einsum("ab,vbk->vak", outside[-1], J_p)
            J[row:row + n, :, pr.sl] = J_p
            row += n
        return J.reshape(3 * n_rows, self.n_params)


# ----------------------------------------------------------------------------------------------
# Files
# ----------------------------------------------------------------------------------------------

def mesh_node_from_dict(d: object, path: str = "root") -> MeshNode:
    """A node tree from nested JSON data; errors name the node path."""
    if not isinstance(d, Mapping):
        raise ValueError(f"node {path}: expected an object with a 'node' field, got {type(d).__name__}")
    if "node" not in d:
        raise ValueError(f"node {path}: missing the 'node' field (the node type)")
    unknown = set(d) - {"node", "params", "children", "size", "name"}
    if unknown:
        raise ValueError(f"node {path}: unknown field(s) {', '.join(sorted(unknown))}; "
                         "allowed: node, params, children, size, name")
    try:
        cls = mesh_node_type(str(d["node"]))
    except ValueError as e:
        raise ValueError(f"node {path}: {e}") from None
    raw_kids = d.get("children", [])
    if not isinstance(raw_kids, list):
        raise ValueError(f"node {path} ({cls.type_name}): 'children' must be a list")
    kids = tuple(mesh_node_from_dict(c, f"{path}/{i}") for i, c in enumerate(raw_kids))
    params = d.get("params", {})
    if not isinstance(params, Mapping):
        raise ValueError(f"node {path} ({cls.type_name}): 'params' must be an object of name: number")
    size = d.get("size")
    if cls.sized and size is None and params:
        size = cls.size_from_names(list(params))
    try:
        return cls.from_values(dict(params), children=kids, size=size, name=d.get("name"))
    except ValueError as e:
        raise ValueError(f"node {path} ({cls.type_name}): {e}") from None


def mesh_node_to_dict(node: MeshNode) -> dict:
    out: dict = {"node": node.type_name}
    if node.name:
        out["name"] = node.name
    if node.sized:
        out["size"] = node.size
    if node.values:
        out["params"] = {p.name: v for p, v in zip(node.param_defs(), node.values)}
    if node.children:
        out["children"] = [mesh_node_to_dict(c) for c in node.children]
    return out


def mesh_tree_from_json(data: object) -> MeshTree:
    """A tree from ``{"node": ...}`` or ``{"tree": {...}}`` (optionally with ``"generator": "meshtree"``)."""
    if not isinstance(data, Mapping):
        raise ValueError("mesh tree file: expected a JSON object")
    gen = data.get("generator")
    if gen is not None and gen != "meshtree":
        raise ValueError(f"mesh tree file: expected generator 'meshtree', got {gen!r}")
    if "tree" in data:
        data = data["tree"]
    return MeshTree(mesh_node_from_dict(data))


def mesh_tree_to_json(tree: MeshTree | MeshNode) -> dict:
    root = tree.root if isinstance(tree, MeshTree) else tree
    return {"generator": "meshtree", "tree": mesh_node_to_dict(root)}


def is_mesh_tree_file(path: str | Path) -> bool:
    """True if a JSON file declares ``"generator": "meshtree"`` (tells mesh trees from SDF trees)."""
    try:
        data = json.loads(Path(path).read_text())
    except (OSError, json.JSONDecodeError):
        return False
    return isinstance(data, Mapping) and data.get("generator") == "meshtree"


def load_mesh_tree(path: str | Path) -> MeshTree:
    """Read a mesh tree file; ``ValueError`` with a one-line reason on failure."""
    path = Path(path)
    if not path.is_file():
        raise ValueError(f"mesh tree file not found: {path}")
    try:
        data = json.loads(path.read_text())
    except json.JSONDecodeError as e:
        raise ValueError(f"mesh tree file {path} is not valid JSON: {e.msg} at line {e.lineno}") from None
    return mesh_tree_from_json(data)


# ----------------------------------------------------------------------------------------------
# Presets and the generator
# ----------------------------------------------------------------------------------------------

def _n(node, params=None, children=(), name=None, size=None):
    d = {"node": node}
    if name:
        d["name"] = name
    if size is not None:
        d["size"] = size
    if params:
        d["params"] = params
    if children:
        d["children"] = list(children)
    return d


def _at(name, x, y, z, child):
    return _n("translate", {"x": x, "y": y, "z": z}, [child], name=name)


def _table() -> dict:
    legs = [_at(f"leg{i + 1}_at", sx * 0.52, 0.36, sz * 0.32,
                _n("cylinder", {"radius": 0.035, "height": 0.72}, name=f"leg{i + 1}"))
            for i, (sx, sz) in enumerate([(1, 1), (-1, 1), (-1, -1), (1, -1)])]
    top = _at("top_at", 0.0, 0.75, 0.0, _n("box", {"size_x": 1.2, "size_y": 0.06, "size_z": 0.8}, name="top"))
    return _n("merge", children=[top, *legs], name="table")


def _snowman() -> dict:
    def ball(name, y, r):
        return _at(f"{name}_at", 0.0, y, 0.0, _n("uv_sphere", {"radius": r}, name=name))

    nose = _at("nose_at", 0.0, 1.45, 0.24, _n("rotate", {"angle": 90.0, "tilt": 90.0, "azimuth": 0.0},
                                             [_n("cone", {"radius_bottom": 0.04, "radius_top": 0.005,
                                                          "height": 0.16}, name="nose")], name="nose_turn"))
    hat = _at("hat_at", 0.0, 1.68, 0.0, _n("cylinder", {"radius": 0.14, "height": 0.2}, name="hat"))
    brim = _at("brim_at", 0.0, 1.59, 0.0, _n("cylinder", {"radius": 0.24, "height": 0.025}, name="brim"))
    arms = [_at(f"arm{i + 1}_at", s * 0.48, 1.08, 0.0,
                _n("rotate", {"angle": -s * 60.0, "tilt": 90.0, "azimuth": 90.0},
                   [_n("cylinder", {"radius": 0.02, "height": 0.45}, name=f"arm{i + 1}")],
                   name=f"arm{i + 1}_turn"))
            for i, s in enumerate((1, -1))]
    body = _n("merge", children=[ball("bottom", 0.4, 0.4), ball("middle", 1.02, 0.3), ball("head", 1.45, 0.2),
                                 nose, brim, hat, *arms], name="parts")
    return _n("scale", {"factor": 1.0}, [body], name="snowman")


def _lamp() -> dict:
    hexagon = {"height": 0.06}
    for i in range(6):
        a = 2.0 * math.pi * i / 6
        hexagon[f"x{i}"] = round(0.3 * math.cos(a), 6)
        hexagon[f"z{i}"] = round(-0.3 * math.sin(a), 6)
    base = _at("base_at", 0.0, 0.03, 0.0, _n("extrude", hexagon, name="base", size=6))
    stem = _at("stem_at", 0.0, 0.66, 0.0, _n("cylinder", {"radius": 0.025, "height": 1.2}, name="stem"))
    shade = _n("revolve", {"r0": 0.36, "y0": 1.0, "r1": 0.3, "y1": 1.2, "r2": 0.2, "y2": 1.45},
               name="shade", size=3)
    knob = _at("knob_at", 0.0, 1.5, 0.0, _n("uv_sphere", {"radius": 0.04}, name="knob"))
    return _n("scale3", {"sx": 1.0, "sy": 1.0, "sz": 1.0},
              [_n("merge", children=[base, stem, shade, knob], name="parts")], name="lamp")


TREE_PRESETS = {"table": _table, "snowman": _snowman, "lamp": _lamp}


def mesh_tree_presets() -> tuple[str, ...]:
    """Names of the shipped mesh trees."""
    return tuple(TREE_PRESETS)


class MeshTreeGenerator(Generator):
    """Generator over one mesh tree (all parameters continuous; ``discrete`` is ignored)."""

    kind = "mesh"

    def __init__(self, tree: MeshTree, name: str = "meshtree", source: str | None = None,
                 presets: Mapping[str, Mapping[str, Value]] | None = None):
        self.tree = tree
        self.name = name
        self.source = source
        self.spec = tree.spec
        self.presets = dict(presets or {})
        self.description = f"mesh tree from {source}" if source else "mesh tree"

    @staticmethod
    def from_file(path: str | Path) -> MeshTreeGenerator:
        return MeshTreeGenerator(load_mesh_tree(path), "meshtree", str(path))

    @staticmethod
    def from_preset(name: str) -> MeshTreeGenerator:
        if name not in TREE_PRESETS:
            raise ValueError(f"unknown mesh tree preset {name!r}; known: {', '.join(TREE_PRESETS)}")
        return MeshTreeGenerator(mesh_tree_from_json(TREE_PRESETS[name]()), "meshtree", f"preset {name}",
                                 VALUE_PRESETS.get(name))

    def mesh(self, theta: torch.Tensor, discrete: Mapping[str, int] | None = None, lod=None) -> TriMesh:
        """The tree's mesh for ``theta: (n,) float``; groups are the primitives' labels."""
        return self.tree.mesh(theta, lod)

    def jacobian(self, theta: torch.Tensor, discrete: Mapping[str, int] | None = None,
                 lod=None) -> torch.Tensor:
        """``(3V, n)`` Jacobian of the vertices from per-vertex 3x3 blocks (see :meth:`MeshTree.jacobian`)."""
        return self.tree.jacobian(theta, lod)

    def to_mesh(self, values: Mapping[str, Value], *, resolution: int | None = None, lod=None) -> TriMesh:
        """The mesh of a value dict at level of detail ``lod`` (``resolution`` is for SDF generators)."""
        return self.tree.mesh(self.spec.to_vector(self.spec.validate(values)), lod).detach()

    def metadata(self, values: Mapping[str, Value]) -> dict:
        return {"generator": self.name, "params": dict(values),
                "tree": mesh_tree_to_json(self.tree.with_values(values))["tree"]}


# value variants of the shipped trees (the generator's presets)
VALUE_PRESETS: dict[str, dict[str, dict[str, Value]]] = {
    "table": {
        "table": {},
        "coffee_table": {"top_at.y": 0.42, "top.size_x": 1.1, "top.size_z": 0.6,
                         **{f"leg{i}.height": 0.4 for i in range(1, 5)},
                         **{f"leg{i}_at.y": 0.2 for i in range(1, 5)}},
        "bar_table": {"top_at.y": 1.05, "top.size_x": 0.7, "top.size_z": 0.7,
                      **{f"leg{i}.height": 1.02 for i in range(1, 5)},
                      **{f"leg{i}_at.y": 0.51 for i in range(1, 5)},
                      **{f"leg{i}_at.x": s * 0.3 for i, s in zip(range(1, 5), (1, -1, -1, 1))},
                      **{f"leg{i}_at.z": s * 0.3 for i, s in zip(range(1, 5), (1, 1, -1, -1))}},
    },
}


@register_generator("meshtree", from_file=MeshTreeGenerator.from_file)
def _meshtree() -> MeshTreeGenerator:
    """``meshtree`` alone is the table; other trees: :meth:`MeshTreeGenerator.from_preset` / ``from_file``."""
    return MeshTreeGenerator.from_preset("table")
