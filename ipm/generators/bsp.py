"""BSP: a shape as a union of convexes, each the intersection of half-spaces chosen from a shared set of
planes (Chen, Tagliasacchi, Zhang: "BSP-Net: Generating Compact Meshes via Binary Space Partitioning",
CVPR 2020), used per shape, without the network.

Planes. ``p`` planes, each ``(a (3,), d)``: the unit normal is ``n = a / sqrt(|a|^2 + EPS^2)`` (``a``
unnormalized, so the parameters have no singular chart; ``EPS`` keeps the gradient finite at ``a = 0``)
and the signed plane distance ``D_i(x) = n_i . x - d_i`` is negative on the kept side (the paper's
``D = P x``, eq. 1). Six fixed planes of a domain box ``|x_k| <= extent`` belong to every convex, so
every convex is bounded (this also makes the exact polytope export well posed).

Selection ``T (p, c)``: plane ``i`` bounds convex ``j`` when ``T_ij = 1``; union weights ``W (c,)``:
convex ``j`` belongs to the shape when ``W_j = 1`` (the paper's ``T`` and ``W``, sec. 3.1).

Stage 1 (relaxed; ``T`` in [0, 1] and ``W`` in [0, 1] are part of ``theta``)::

    Z_ij(x) = T_ij (D_i(x) + R) - R           # T = 1: the plane itself; T -> 0: pushed out of reach
    g_j(x)  = tau * logsumexp_i(Z_ij / tau)   # smooth intersection (a smooth maximum)
    h_j(x)  = W_j (g_j(x) - R) + R            # W = 1: the convex; W -> 0: removed from the union
    f(x)    = -tau * logsumexp_j(-h_j / tau)  # smooth union (a smooth minimum)

The paper relaxes the same structure as ``C_j = sum_i relu(D_i) T_ij`` (eq. 2) with a weighted soft
union ``sum_j W_j [1 - C_j]`` of occupancies (eq. 3). That field is zero inside every convex, so it
cannot serve the project's "negative inside" SDF contract (sphere tracing, narrow-band meshing, the
surface losses of the fitter). Ours keeps the paper's roles of ``T`` and ``W`` and is negative inside
and 1-Lipschitz (every ``Z_ij`` is, ``T, W <= 1`` only lower slopes, and smooth max / min keep it), so
``|f|`` never exceeds the distance to its zero set: a valid bound for narrow-band meshing and sphere
tracing. ``R`` (``relax``) and ``tau`` (``temperature``) are fixed settings of a generator.

Stage 2 (discrete; ``T`` binary and fixed, not in ``theta``; convexes without a plane are absent)::

    g_j(x) = max_{i: T_ij = 1} D_i(x)         # hard intersection: exact inside, a bound outside
    f(x)   = min_j g_j(x)                     # hard union (the paper's eq. 4, as a min of convexes)

:meth:`BspGenerator.to_mesh` exports the exact polytope mesh when ``T`` (and ``W``) are binary: every
convex as the intersection of its half-spaces (``scipy.spatial.HalfspaceIntersection`` from a
Chebyshev-center interior point found by ``scipy.optimize.linprog``; empty convexes are skipped),
hulled and united by manifold3d. No marching cubes, sharp edges. A relaxed ``T`` is meshed by
marching cubes.

A file (``{"generator": "bsp", ...}``, see :meth:`BspGenerator.to_json`) stores the settings, the
selection (stage 2) and the parameter values; ``get_generator(path)`` and ``ipm generate path`` load it.
"""

from __future__ import annotations

import logging
from collections.abc import Mapping
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import torch

from ipm.errors import InputError
from ipm.generators.base import Generator, ValuesField, check_field_meshing, check_format, register_generator
from ipm.params import Param, ParamSpec, Value
from ipm.types import TriMesh

log = logging.getLogger(__name__)

EPS = 1e-6          # normal normalization guard: n = a / sqrt(|a|^2 + EPS^2)
CHUNK = 1 << 16     # points per evaluation chunk (the relaxed field holds (chunk, c, p + 6) values)
BIG = 1e6           # "minus infinity" for unselected planes (keeps where() gradients finite)
FORMAT = "bsp"


def plane_names(p: int) -> list[str]:
    """Parameter names of ``p`` planes: ``plane<i>.nx|ny|nz|d``."""
    return [f"plane{i}.{k}" for i in range(p) for k in ("nx", "ny", "nz", "d")]


def selection_names(p: int, c: int) -> list[str]:
    """Parameter names of a relaxed selection ``T (p, c)``: ``sel<i>.<j>`` (row-major)."""
    return [f"sel{i}.{j}" for i in range(p) for j in range(c)]


def weight_names(c: int) -> list[str]:
    """Parameter names of the relaxed union weights ``W (c,)``: ``conv<j>.w``."""
    return [f"conv{j}.w" for j in range(c)]


def plane_distances(planes: torch.Tensor, points: torch.Tensor, extent: float) -> torch.Tensor:
    """Signed distances ``(..., p + 6)`` of ``points (..., 3)`` to ``p`` planes ``(p, 4)`` (a, d) and the
    six domain-box planes (last), negative on the kept side. dtype and device follow ``points``."""
    planes = planes.to(points.dtype)
    a, d = planes[:, :3], planes[:, 3]
    n = a / torch.sqrt((a * a).sum(-1, keepdim=True) + EPS * EPS)
    D = points @ n.T - d
    box = torch.cat([points - extent, -points - extent], -1)
    return torch.cat([D, box], -1)


def relaxed_field(planes: torch.Tensor, T: torch.Tensor, W: torch.Tensor, points: torch.Tensor, extent: float,
                  relax: float, tau: float) -> torch.Tensor:
    """Stage-1 field ``(...)`` (module docstring) at ``points (..., 3)`` for ``planes (p, 4)``, the selection
    ``T (p, c)`` and the union weights ``W (c,)``, both clamped to [0, 1]. dtype follows ``points``."""
    D = plane_distances(planes, points, extent)                                    # (..., p + 6)
    Tb = torch.cat([T.to(points.dtype).clamp(0.0, 1.0),
                    torch.ones(6, T.shape[1], dtype=points.dtype, device=points.device)], 0).T
    Z = Tb * (D[..., None, :] + relax) - relax                                     # (..., c, p + 6)
    g = tau * torch.logsumexp(Z / tau, dim=-1)                                     # (..., c)
    h = W.to(points.dtype).clamp(0.0, 1.0) * (g - relax) + relax
    return -tau * torch.logsumexp(-h / tau, dim=-1)


def hard_field(planes: torch.Tensor, mask: torch.Tensor, points: torch.Tensor, extent: float) -> torch.Tensor:
    """Stage-2 field ``(...)``: ``mask (p + 6, c)`` bool (the six box rows all True) selects the planes
    of each convex; ``max`` over a convex's planes, ``min`` over the convexes."""
    D = plane_distances(planes, points, extent)
    g = torch.where(mask.T, D[..., None, :], torch.full_like(D[..., None, :], -BIG)).amax(-1)
    return g.amin(-1)


def convex_fields(planes: torch.Tensor, mask: torch.Tensor, points: torch.Tensor, extent: float) -> torch.Tensor:
    """Per-convex hard fields ``(..., c)`` (before the union) for ``mask (p + 6, c)``."""
    D = plane_distances(planes, points, extent)
    return torch.where(mask.T, D[..., None, :], torch.full_like(D[..., None, :], -BIG)).amax(-1)


def _chunked(fn, points: torch.Tensor) -> torch.Tensor:
    if points.dim() == 2 and points.shape[0] > 2 * CHUNK:
        return torch.cat([fn(points[i:i + CHUNK]) for i in range(0, points.shape[0], CHUNK)])
    return fn(points)


# ----------------------------------------------------------------------------------------------
# Exact polytope export
# ----------------------------------------------------------------------------------------------

@dataclass(frozen=True)
class Polytope:
    """The exact union mesh and what it used: the non-empty convexes and the planes that carry a face
    (at least three vertices) of one of them."""

    mesh: TriMesh
    convexes: list[int]
    planes: list[int]


def convex_vertices(normals: np.ndarray, offsets: np.ndarray, tol: float = 1e-9) -> np.ndarray | None:
    """Vertices ``(k, 3)`` of ``{x: normals @ x <= offsets}`` (a bounded set; unit ``normals (m, 3)``), or
    None if it is empty or flat (Chebyshev radius <= ``tol``).

    The interior point is the Chebyshev center (``max r`` s.t. ``n_i . x + r |n_i| <= d_i``, a linear
    program), which qhull's half-space intersection needs strictly inside."""
    from scipy.optimize import linprog
    from scipy.spatial import HalfspaceIntersection
    from scipy.spatial._qhull import QhullError

    m = len(normals)
    A = np.hstack([normals, np.linalg.norm(normals, axis=1, keepdims=True)])
    res = linprog(np.array([0.0, 0.0, 0.0, -1.0]), A_ub=A, b_ub=offsets,
                  bounds=[(None, None)] * 3 + [(0.0, None)], method="highs")
    if res.status != 0 or res.x[3] <= tol:
        return None
    hs = np.hstack([normals, -offsets.reshape(m, 1)])
    try:
        v = HalfspaceIntersection(hs, res.x[:3]).intersections
    except QhullError:
        log.debug("half-space intersection failed for a convex with Chebyshev radius %.3g", res.x[3])
        return None
    v = v[np.isfinite(v).all(1)]
    return v if len(v) >= 4 else None


def convex_cells(planes, selection, extent: float):
    """Each non-empty convex of a binary BSP as ``(j, idx, N, off, vertices)``: its index, the indices of
    its planes, the unit normals and offsets of its half-spaces ``N x <= off`` (the domain box
    ``|x| <= extent`` appended) and its vertices. planes: ``(p, 4)`` (a, d); selection: ``(p, c)`` bool."""
    planes = np.asarray(planes, dtype=np.float64)
    sel = np.asarray(selection, dtype=bool)
    a, d = planes[:, :3], planes[:, 3]
    n = a / np.sqrt((a * a).sum(1, keepdims=True) + EPS * EPS)
    scale = np.linalg.norm(n, axis=1)                # < 1 only for (near) zero a; keep n . x <= d exact
    box_n = np.vstack([np.eye(3), -np.eye(3)])
    for j in range(sel.shape[1]):
        idx = np.flatnonzero(sel[:, j] & (scale > 1e-3))
        if not sel[:, j].any():
            continue
        N = np.vstack([n[idx] / scale[idx, None], box_n])
        off = np.concatenate([d[idx] / scale[idx], np.full(6, extent)])
        v = convex_vertices(N, off)
        if v is not None:
            yield j, idx, N, off, v


def polytope_mesh(planes: np.ndarray, selection: np.ndarray, extent: float, tol: float = 1e-9) -> Polytope:
    """Exact union of the convexes ``selection[:, j]`` (bool ``(p, c)``) of ``planes (p, 4)`` (a, d), each
    clipped to the domain box; a convex without a plane of its own is absent (as in the field).

    Returns a :class:`Polytope` (float64 vertices, outward faces; an empty mesh if every convex is empty).
    """
    import manifold3d as m3d

    parts, used_convexes, used_planes = [], [], set()
    for j, idx, N, off, v in convex_cells(planes, selection, extent):
        hull = m3d.Manifold.hull_points(v)
        if hull.is_empty() or hull.volume() <= tol:
            continue
        parts.append(hull)
        used_convexes.append(j)
        on = np.abs(v @ N[: len(idx)].T - off[: len(idx)]) <= 1e-7 * max(1.0, extent)
        used_planes.update(int(i) for i, k in zip(idx, on.sum(0)) if k >= 3)
    if not parts:
        empty = TriMesh(torch.zeros(0, 3, dtype=torch.float64), torch.zeros(0, 3, dtype=torch.int64))
        return Polytope(empty, [], [])
    union = m3d.Manifold.batch_boolean(parts, m3d.OpType.Add) if len(parts) > 1 else parts[0]
    out = union.to_mesh64()
    V = np.asarray(out.vert_properties, dtype=np.float64)[:, :3]
    F = np.asarray(out.tri_verts, dtype=np.int64)
    return Polytope(TriMesh(torch.from_numpy(V.copy()), torch.from_numpy(F.copy())), used_convexes,
                    sorted(used_planes))


# ----------------------------------------------------------------------------------------------
# The field object handed to fitting, rendering and the CLI (like ipm.sdf.nodes.Tree)
# ----------------------------------------------------------------------------------------------

class BspField(ValuesField):
    """A BSP field with stored parameter values: ``sdf(theta, points)``, ``with_theta``, ``with_values``,
    ``bounds`` (the interface of :class:`ipm.sdf.nodes.Tree` that fitting and the CLI use)."""

    def _eval(self, theta: torch.Tensor, points: torch.Tensor) -> torch.Tensor:
        return self.gen.field(theta.to(points.dtype), points)

    def bounds(self) -> tuple[np.ndarray, np.ndarray]:
        """The domain box ``(lo (3,), hi (3,))``: it contains every convex."""
        e = self.gen.extent
        return np.full(3, -e), np.full(3, e)


# ----------------------------------------------------------------------------------------------
# The generator
# ----------------------------------------------------------------------------------------------

def fibonacci_directions(k: int) -> np.ndarray:
    """``k`` unit vectors ``(k, 3)`` spread evenly over the sphere (Fibonacci lattice)."""
    i = np.arange(k) + 0.5
    z = 1.0 - 2.0 * i / k
    phi = np.pi * (1.0 + 5.0 ** 0.5) * i
    r = np.sqrt(np.maximum(1.0 - z * z, 0.0))
    return np.stack([r * np.cos(phi), r * np.sin(phi), z], 1)


def _load(path: str) -> BspGenerator:
    return BspGenerator.from_file(path)


@register_generator("bsp", from_file=_load)
class BspGenerator(Generator):
    """Union of convexes from ``planes`` shared planes and ``convexes`` convexes.

    selection: None for the relaxed stage (``T`` and ``W`` in ``theta`` as ``sel<i>.<j>`` and
    ``conv<j>.w``), or a binary ``(planes, convexes)`` array (stage 2; only the planes are parameters).
    values: parameter values (missing ones take the defaults). The defaults: planes along evenly spread
    directions at distances 0.5 to 0.8 from the origin; a seeded random relaxed ``T`` and ``W = 1``,
    so the default shape is a union of random polytopes around the origin (a start for ``ipm fit``).
    """

    kind = "sdf"
    description = "BSP-Net style union of convexes (planes + selection); exact polytope export"

    def __init__(self, planes: int = 24, convexes: int = 6, selection: np.ndarray | None = None,
                 values: Mapping[str, float] | None = None, *, extent: float = 1.5, relax: float = 1.0,
                 temperature: float = 0.02, seed: int = 0, name: str = "bsp"):
        if isinstance(planes, bool) or not (isinstance(planes, (int, np.integer)) and planes >= 1):
            raise InputError(f"planes: expected a positive integer, got {planes!r}")
        if isinstance(convexes, bool) or not (isinstance(convexes, (int, np.integer)) and convexes >= 1):
            raise InputError(f"convexes: expected a positive integer, got {convexes!r}")
        for label, v in (("extent", extent), ("relax", relax), ("temperature", temperature)):
            if not (isinstance(v, (int, float)) and np.isfinite(v) and v > 0):
                raise InputError(f"{label}: expected a positive number, got {v!r}")
        self.name = name
        self.n_planes, self.n_convexes = int(planes), int(convexes)
        self.extent, self.relax, self.temperature = float(extent), float(relax), float(temperature)
        self.selection: np.ndarray | None = None
        if selection is not None:
            sel = np.asarray(selection)
            if sel.shape != (self.n_planes, self.n_convexes):
                raise InputError(f"selection: expected shape ({self.n_planes}, {self.n_convexes}), got {sel.shape}")
            if not np.isin(sel, (0, 1)).all():
                raise InputError("selection: expected a binary (0/1) matrix, got other values")
            self.selection = sel.astype(bool)
        self.presets = {}
        default = self._default_values(seed)
        if values is not None:
            unknown = set(values) - set(default)
            if unknown:
                raise InputError(f"unknown parameter(s) {', '.join(sorted(unknown)[:5])}; expected plane<i>.nx|ny|nz|d"
                                 + ("" if self.selection is not None else ", sel<i>.<j> or conv<j>.w")
                                 + f" with i < {self.n_planes}, j < {self.n_convexes}")
            default.update({k: float(v) for k, v in values.items()})
        self.spec = ParamSpec(tuple(self._param(k, v) for k, v in default.items()))
        self._mask_cache: dict = {}
        self.tree = BspField(self, self.spec.defaults())

    # -- parameters ----------------------------------------------------------------------------
    def _default_values(self, seed: int) -> dict[str, float]:
        rng = np.random.default_rng(seed)
        n = fibonacci_directions(self.n_planes)
        planes = np.hstack([n, rng.uniform(0.5, 0.8, size=(self.n_planes, 1))])
        out = dict(zip(plane_names(self.n_planes), planes.reshape(-1).tolist()))
        if self.selection is None:
            T = rng.uniform(0.0, 1.0, size=(self.n_planes, self.n_convexes))
            out.update(zip(selection_names(self.n_planes, self.n_convexes), T.reshape(-1).tolist()))
            out.update(zip(weight_names(self.n_convexes), [1.0] * self.n_convexes))
        return out

    def _param(self, name: str, value: float) -> Param:
        if name.startswith("sel"):
            return Param(name, min(max(value, 0.0), 1.0), 0.0, 1.0, "float", "membership of a plane in a convex")
        if name.startswith("conv"):
            return Param(name, min(max(value, 0.0), 1.0), 0.0, 1.0, "float", "membership of a convex in the union")
        if name.endswith(".d"):
            lim = max(2.0 * self.extent, abs(value))
            return Param(name, value, -lim, lim, "float", "plane offset along its unit normal")
        lim = max(1.0, abs(value))
        return Param(name, value, -lim, lim, "float", "plane normal component (normalized inside)")

    @property
    def relaxed(self) -> bool:
        """True in stage 1 (``T`` and ``W`` are parameters), False in stage 2 (binary ``T``)."""
        return self.selection is None

    def _mask(self, device) -> torch.Tensor:
        key = str(device)
        if key not in self._mask_cache:
            m = np.vstack([self.selection, np.ones((6, self.n_convexes), bool)])
            keep = self.selection.any(0)           # a convex with no plane of its own is absent, not the box
            self._mask_cache[key] = torch.as_tensor(m[:, keep], device=device)
        return self._mask_cache[key]

    # -- geometry ------------------------------------------------------------------------------
    def field(self, theta: torch.Tensor, points: torch.Tensor) -> torch.Tensor:
        """The stage's field ``(...)`` at ``points (..., 3)`` for ``theta (n,)`` (dtype of the points)."""
        p, c = self.n_planes, self.n_convexes
        planes = theta[: 4 * p].reshape(p, 4)
        if self.relaxed:
            T = theta[4 * p: 4 * p + p * c].reshape(p, c)
            W = theta[4 * p + p * c: 4 * p + p * c + c]
            return _chunked(lambda q: relaxed_field(planes, T, W, q, self.extent, self.relax, self.temperature),
                            points)
        mask = self._mask(points.device)
        if mask.shape[1] == 0:                     # no convex at all: empty shape, outside everywhere
            return plane_distances(planes, points, self.extent)[..., -6:].amax(-1).abs() + 1.0
        return _chunked(lambda q: hard_field(planes, mask, q, self.extent), points)

    def tree_for(self, discrete: Mapping[str, int] | None = None) -> BspField:
        """The field object (no discrete parameters: the selection is fixed structure)."""
        return self.tree

    def sdf(self, theta: torch.Tensor, points: torch.Tensor, discrete: Mapping[str, int] | None = None):
        """Field ``(...)`` at ``points (..., 3)``, negative inside; differentiable in ``theta`` and points."""
        return self.field(theta.to(points.dtype), points)

    def planes_and_selection(self, values: Mapping[str, Value]) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """``(planes (p, 4), T (p, c), W (c,))`` float64: the binary selection and ones in stage 2, the
        relaxed values in stage 1."""
        full = self.spec.validate(values)
        planes = np.array([full[k] for k in plane_names(self.n_planes)], dtype=np.float64).reshape(-1, 4)
        if not self.relaxed:
            return planes, self.selection.astype(np.float64), np.ones(self.n_convexes)
        T = np.array([full[k] for k in selection_names(self.n_planes, self.n_convexes)], dtype=np.float64)
        W = np.array([full[k] for k in weight_names(self.n_convexes)], dtype=np.float64)
        return planes, T.reshape(self.n_planes, self.n_convexes), W

    def polytope(self, values: Mapping[str, Value], threshold: float = 0.5) -> Polytope:
        """Exact polytope of the selection (a relaxed ``T`` and ``W`` are thresholded at ``threshold``)."""
        planes, T, W = self.planes_and_selection(values)
        return polytope_mesh(planes, (T >= threshold) & (W >= threshold), self.extent)

    def check_meshing(self, values: Mapping[str, Value], resolution: int) -> None:
        """Marching cubes over the field's bounds: the grid must fit in memory (:func:`check_field_meshing`)."""
        check_field_meshing(self.tree, values, resolution)

    def to_mesh(self, values: Mapping[str, Value], *, resolution: int | None = None, lod=None) -> TriMesh:
        """Exact polytope mesh when ``T`` and ``W`` are binary; marching cubes of the relaxed field otherwise."""
        planes, T, W = self.planes_and_selection(values)
        if np.isin(T, (0.0, 1.0)).all() and np.isin(W, (0.0, 1.0)).all():
            return polytope_mesh(planes, (T >= 0.5) & (W >= 0.5), self.extent).mesh
        from ipm.sdf.meshing import mesh_sdf

        field = self.tree.with_values(values)
        return mesh_sdf(lambda q: field.sdf(None, q), *field.bounds(), resolution or 128)

    # -- files ---------------------------------------------------------------------------------
    def settings(self) -> dict:
        """The structural settings a bsp file records: plane and convex counts, extent, relaxation, temperature."""
        return {"planes": self.n_planes, "convexes": self.n_convexes, "extent": self.extent,
                "relax": self.relax, "temperature": self.temperature}

    def to_json(self, values: Mapping[str, Value] | None = None, **extra) -> dict:
        """``{"generator": "bsp", planes, convexes, extent, relax, temperature, selection?, params, ...}``."""
        out: dict = {"generator": FORMAT, **self.settings()}
        if not self.relaxed:
            out["selection"] = self.selection.astype(int).tolist()
        out["params"] = dict(self.spec.validate(values or {}))
        out.update(extra)
        return out

    def metadata(self, values: Mapping[str, Value]) -> dict:
        """The whole file document (:meth:`to_json`), so exports can be loaded back as a generator."""
        return self.to_json(values)

    @staticmethod
    def from_json(data: Mapping) -> BspGenerator:
        """A generator from :meth:`to_json`'s document; ``ValueError`` says what is missing or wrong."""
        check_format(data, FORMAT, "bsp file")
        missing = [k for k in ("planes", "convexes", "params") if k not in data]
        if missing:
            raise InputError(f"bsp file: expected fields planes, convexes, params; missing {', '.join(missing)}")
        if not isinstance(data["params"], Mapping):
            raise InputError("bsp file: expected 'params' to be an object of name: number")
        try:
            kw = {k: float(data[k]) for k in ("extent", "relax", "temperature") if k in data}
            p, c = int(data["planes"]), int(data["convexes"])
        except (TypeError, ValueError):
            raise InputError("bsp file: expected numbers for planes, convexes, extent, relax, temperature") from None
        return BspGenerator(p, c, data.get("selection"), dict(data["params"]), **kw)

    @staticmethod
    def from_file(path: str | Path) -> BspGenerator:
        """Load a file written by :meth:`to_json` (``ipm convert --to bsp``)."""
        from ipm.files import read_json

        data = read_json(path, "bsp file")
        return BspGenerator.from_json(data)
