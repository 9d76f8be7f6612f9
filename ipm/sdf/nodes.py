"""SDF nodes as immutable data, their registry, and trees compiled to torch functions.

A node type is a small class: a registry name, its dimension (2 or 3), how many children it takes and
of which dimension, its named parameters (with bounds and defaults) and one vectorized
``eval(p, th, kids) -> distances``. ``th`` holds the node's parameter values in declaration order
(0-dim tensors for continuous ones, Python ints for discrete ones); ``kids`` are callables
``q -> distances`` evaluating the children at transformed points. A node *instance* is frozen data:
its type, its parameter values and its children. A :class:`Tree` flattens an instance tree into one
:class:`~ipm.params.ParamSpec` and evaluates it for any parameter vector ``theta``.

Convention: signed distance is negative inside; 3D points are ``(..., 3)``, 2D points ``(..., 2)``.
"""

from __future__ import annotations

from abc import ABC, abstractmethod
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass, field
from typing import ClassVar

import numpy as np
import torch

from ipm.params import Param, ParamSpec
from ipm.sdf._math import coord_major

Eval = Callable[[torch.Tensor], torch.Tensor]
Box = tuple[np.ndarray, np.ndarray]

NODE_TYPES: dict[str, type[Node]] = {}
EVAL_CHUNK = 1 << 18


def register(cls: type[Node]) -> type[Node]:
    """Class decorator: add a node type to the registry under ``cls.type_name``."""
    if not getattr(cls, "type_name", None):
        raise ValueError(f"{cls.__name__}: node types need a type_name")
    if cls.type_name in NODE_TYPES and NODE_TYPES[cls.type_name] is not cls:
        raise ValueError(f"node type {cls.type_name!r} is registered twice")
    NODE_TYPES[cls.type_name] = cls
    return cls


def node_type(name: str) -> type[Node]:
    """Look a node type up by name; ``ValueError`` lists the known names."""
    _load_builtin_nodes()
    try:
        return NODE_TYPES[name]
    except KeyError:
        raise ValueError(f"unknown node type {name!r}; known: {', '.join(sorted(NODE_TYPES))}") from None


_BUILTINS_LOADED = False


def _load_builtin_nodes() -> None:
    global _BUILTINS_LOADED
    if not _BUILTINS_LOADED:
        _BUILTINS_LOADED = True
        from ipm.sdf import complex as _complex  # noqa: F401  (registers shipped macro nodes)
        from ipm.sdf import d2, d3, dn, lift, transforms  # noqa: F401
        _complex.load_library()


def all_node_types() -> dict[str, type[Node]]:
    _load_builtin_nodes()
    return dict(NODE_TYPES)


@dataclass(frozen=True, eq=False)
class Node(ABC):
    """An SDF node instance: immutable values and children.

    Class attributes (set by each node type):
      type_name: registry key; dim: 2 or 3, or 0 for "same as the children" (CSG);
      child_dim: dimension required of the children (default: ``dim``);
      arity: number of children, or ``None`` for two or more; exact: True (exact distance),
      False (a bound or an approximation); params: the parameter declarations;
      sized: True if the number of parameters depends on ``size`` (polygons, profiles).
    """

    values: tuple = ()
    children: tuple[Node, ...] = ()
    size: int | None = None
    name: str | None = None
    _dim: int = field(default=0, repr=False)

    type_name: ClassVar[str] = ""
    dim: ClassVar[int] = 3
    child_dim: ClassVar[int | None] = None
    arity: ClassVar[int | None] = 0
    exact: ClassVar[bool] = False
    params: ClassVar[tuple[Param, ...]] = ()
    sized: ClassVar[bool] = False
    default_size: ClassVar[int | None] = None
    min_size: ClassVar[int] = 1

    # -- declarations ---------------------------------------------------------------------------
    @classmethod
    def param_defs_for(cls, size: int | None) -> tuple[Param, ...]:
        """Parameter declarations of an instance of the given size (sized nodes override)."""
        return cls.params

    def param_defs(self) -> tuple[Param, ...]:
        return type(self).param_defs_for(self.size)

    @property
    def out_dim(self) -> int:
        """Dimension of this instance's output (CSG nodes take their children's)."""
        return self._dim or type(self).dim

    # -- construction ---------------------------------------------------------------------------
    @classmethod
    def make(cls, *args, children: Sequence[Node] = (), size: int | None = None,
             name: str | None = None, **kwargs) -> Node:
        """Build an instance: positional values (sequences are flattened) then keyword values.

        Missing values take their defaults. Values are checked against the declared bounds.
        """
        if cls.sized:
            size = cls.default_size if size is None else int(size)
            if size is None or size < cls.min_size:
                raise ValueError(f"{cls.type_name}: expected size >= {cls.min_size}, got {size}")
        defs = cls.param_defs_for(size)
        flat: list = []
        for a in args:
            if isinstance(a, (list, tuple, np.ndarray)) or (torch.is_tensor(a) and a.ndim > 0):
                flat.extend(float(x) for x in (a.tolist() if hasattr(a, "tolist") else a))
            else:
                flat.append(a)
        if len(flat) > len(defs):
            raise ValueError(f"{cls.type_name}: expected at most {len(defs)} values "
                             f"({', '.join(p.name for p in defs)}), got {len(flat)}")
        given = {p.name: v for p, v in zip(defs, flat)}
        for k, v in kwargs.items():
            if k in given:
                raise ValueError(f"{cls.type_name}: value for {k!r} given twice")
            given[k] = v
        return cls.from_values(given, children=children, size=size, name=name)

    @classmethod
    def from_values(cls, given: Mapping[str, object], *, children: Sequence[Node] = (),
                    size: int | None = None, name: str | None = None) -> Node:
        """Build an instance from named values (missing ones take their defaults), checking bounds."""
        if cls.sized:
            size = cls.default_size if size is None else int(size)
            if size is None or size < cls.min_size:
                raise ValueError(f"{cls.type_name}: expected size >= {cls.min_size}, got {size}")
        defs = cls.param_defs_for(size)
        values = ParamSpec(defs).validate(given)
        return cls._new(tuple(values[p.name] for p in defs), tuple(children), size, name)

    @classmethod
    def _new(cls, values: tuple, children: tuple, size: int | None, name: str | None) -> Node:
        kids = tuple(children)
        check_children(cls, kids, size)
        dim = cls.dim or (kids[0].out_dim if kids else 3)
        return cls(values=tuple(values), children=kids, size=size, name=name, _dim=dim)

    def replace(self, *, values: tuple | None = None, children: tuple | None = None) -> Node:
        return type(self)._new(self.values if values is None else values,
                               self.children if children is None else children, self.size, self.name)

    # -- behaviour (overridden) -----------------------------------------------------------------
    @abstractmethod
    def eval(self, p: torch.Tensor, th: tuple, kids: Sequence[Eval]) -> torch.Tensor:
        """Signed distances at points ``p: (..., dim)`` -> ``(...)``."""

    @abstractmethod
    def bbox(self, v: tuple, kids: Sequence[Box]) -> Box:
        """Conservative axis-aligned bounds (lo, hi) of the solid, from float values ``v``."""

    # -- python composition ---------------------------------------------------------------------
    def __or__(self, other: Node) -> Node:
        return node_type("union").make(children=(self, other))

    def __and__(self, other: Node) -> Node:
        return node_type("intersection").make(children=(self, other))

    def __sub__(self, other: Node) -> Node:
        return node_type("subtraction").make(children=(self, other))

    def __getattr__(self, attr: str):
        # Chaining: box(...).translate(...) builds the unary node "translate" (or its 2D variant)
        # with this node as child. Only names of registered one-child node types are accepted.
        if attr.startswith("_"):
            raise AttributeError(attr)
        types = all_node_types()
        dim = self.out_dim
        for cand in ((f"{attr}2d", attr) if dim == 2 else (attr,)):
            cls = types.get(cand)
            if cls is not None and cls.arity == 1 and (cls.child_dim or cls.dim or dim) == dim:
                def chain(*args, cls=cls, **kwargs):
                    return cls.make(*args, children=(self,), **kwargs)
                return chain
        raise AttributeError(f"{type(self).__name__} has no attribute or unary node {attr!r}")

    def __call__(self, points: torch.Tensor) -> torch.Tensor:
        """Evaluate at points with the stored values."""
        return Tree(self).sdf(None, points)

    def __repr__(self) -> str:
        vals = ", ".join(f"{p.name}={v:g}" for p, v in zip(self.param_defs(), self.values))
        kids = ", ".join(repr(c) for c in self.children)
        inner = ", ".join(x for x in (vals, kids) if x)
        return f"{self.type_name}({inner})"


def check_children(cls: type[Node], kids: tuple[Node, ...], size: int | None = None, path: str = "root") -> None:
    """Arity and dimension rules; errors name the node's path."""
    label = f"node {path} ({cls.type_name})"
    if cls.arity is None:
        if len(kids) < 2:
            raise ValueError(f"{label}: expected at least 2 children, got {len(kids)}")
    elif len(kids) != cls.arity:
        raise ValueError(f"{label}: expected {cls.arity} child{'ren' if cls.arity != 1 else ''}, got {len(kids)}")
    want = cls.child_dim or cls.dim
    if kids:
        dims = {k.out_dim for k in kids}
        if want:
            bad = [k for k in kids if k.out_dim != want]
            if bad:
                raise ValueError(f"{label}: expected {want}D children, got a {bad[0].out_dim}D "
                                 f"{bad[0].type_name}")
        elif len(dims) > 1:
            raise ValueError(f"{label}: children must all be 2D or all 3D, got a mix")


# ----------------------------------------------------------------------------------------------
# Trees: flatten, compile, evaluate
# ----------------------------------------------------------------------------------------------

def _preorder(node: Node, path: str = "root"):
    yield node, path
    for i, c in enumerate(node.children):
        yield from _preorder(c, f"{path}/{i}")


def node_label(node: Node, index: int) -> str:
    return node.name or f"n{index}_{node.type_name}"


class Tree:
    """A validated tree of SDF nodes with a flat parameter vector.

    ``spec`` lists every parameter as ``<label>.<param>`` (label: the node's ``name`` or
    ``n<preorder index>_<type>``). ``theta`` holds the continuous ones in that order; discrete ones
    (counts, axes) are baked into the nodes and changed with :meth:`with_values`.
    """

    def __init__(self, root: Node):
        if not isinstance(root, Node):
            raise ValueError(f"expected an SDF node as the tree root, got {type(root).__name__}")
        if root.out_dim != 3:
            raise ValueError(f"node root ({root.type_name}): the root must be a 3D node, got a 2D node; "
                             "lift 2D shapes with extrude or revolve")
        self.root = root
        self.nodes: list[tuple[Node, str]] = list(_preorder(root))
        params, offsets, off = [], [], 0
        for i, (node, _) in enumerate(self.nodes):
            offsets.append(off)
            label = node_label(node, i)
            for p, v in zip(node.param_defs(), node.values):
                params.append(Param(f"{label}.{p.name}", v, p.lo, p.hi, p.kind, p.doc))
                off += p.continuous
        self.spec = ParamSpec(tuple(params))
        self._offsets = offsets
        counter = iter(range(len(self.nodes)))
        self._fn = _compile(root, counter, offsets)

    def __repr__(self) -> str:
        return f"Tree({self.root!r})"

    @property
    def n_params(self) -> int:
        """Number of continuous parameters (length of ``theta``)."""
        return self.spec.n_continuous

    def theta(self, dtype=torch.float64, device=None) -> torch.Tensor:
        """The stored continuous values, ``(n,)``."""
        return torch.tensor([float(p.default) for p in self.spec.continuous], dtype=dtype, device=device)

    def values(self) -> dict:
        return self.spec.defaults()

    def sdf(self, theta: torch.Tensor | None, points: torch.Tensor) -> torch.Tensor:
        """Signed distance ``(...)`` at ``points: (..., 3)`` for ``theta: (n,)`` (None: stored values).

        ``theta`` is cast to the points' dtype, so float64 points give a float64 evaluation.
        """
        if theta is None:
            theta = self.theta(points.dtype, points.device)
        else:
            theta = theta.to(points.dtype)
        points = coord_major(points)
        n = points.shape[0] if points.dim() == 2 else 0
        if n > 2 * EVAL_CHUNK:
            # cache-sized chunks: ~15% faster at 1e6 points on 2 cores (results/perf/sdf.md)
            return torch.cat([self._fn(points[i:i + EVAL_CHUNK], theta, ()) for i in range(0, n, EVAL_CHUNK)])
        return self._fn(points, theta, ())

    __call__ = sdf

    def with_values(self, values: Mapping[str, object]) -> Tree:
        """A new tree with some parameters (continuous or discrete) replaced by name."""
        full = self.spec.validate(values)
        return Tree(_rebuild(self.root, iter(full[p.name] for p in self.spec.params)))

    def with_theta(self, theta: torch.Tensor) -> Tree:
        """A new tree storing ``theta`` as its continuous values."""
        vals = theta.detach().cpu().double().tolist()
        if len(vals) != self.n_params:
            raise ValueError(f"expected theta of length {self.n_params}, got {len(vals)}")
        named = dict(zip((p.name for p in self.spec.continuous), vals))
        return self.with_values(named)

    def bounds(self) -> Box:
        """Conservative bounding box ``(lo (3,), hi (3,))`` of the solid at the stored values."""
        return _bbox(self.root)


def _rebuild(node: Node, values_iter) -> Node:
    vals = tuple(next(values_iter) for _ in node.param_defs())
    kids = tuple(_rebuild(c, values_iter) for c in node.children)
    return node.replace(values=vals, children=kids)


def _bbox(node: Node) -> Box:
    kids = [_bbox(c) for c in node.children]
    lo, hi = node.bbox(tuple(float(v) for v in node.values), kids)
    return np.asarray(lo, dtype=np.float64), np.asarray(hi, dtype=np.float64)


def _compile(node: Node, counter, offsets) -> Callable:
    """Turn an instance tree into ``f(points, theta, slots) -> distances``."""
    index = next(counter)
    off = offsets[index]
    defs = node.param_defs()
    # For each parameter: ("c", position in theta) or ("d", python int value).
    getters: list[tuple[str, object]] = []
    k = off
    for p, v in zip(defs, node.values):
        if p.continuous:
            getters.append(("c", k))
            k += 1
        else:
            getters.append(("d", int(v)))
    kid_fns = [_compile(c, counter, offsets) for c in node.children]
    has_cont = k > off
    if isinstance(node, SlotNode):
        return lambda points, theta, slots: slots[node.size](points)

    def f(points: torch.Tensor, theta: torch.Tensor, slots: tuple) -> torch.Tensor:
        if has_cont:
            block = theta[off:k].unbind(0) if k - off > 1 else (theta[off],)
            it = iter(block)
            th = tuple(next(it) if kind == "c" else val for kind, val in getters)
        else:
            th = tuple(val for _, val in getters)
        kids = [_bind(fn, theta, slots) for fn in kid_fns]
        return node.eval(points, th, kids)

    return f


def _bind(fn, theta, slots) -> Eval:
    return lambda q: fn(q, theta, slots)


@dataclass(frozen=True, eq=False)
class SlotNode(Node):
    """A placeholder for the i-th child of a macro node (only inside macro definitions)."""

    type_name: ClassVar[str] = "$slot"
    arity: ClassVar[int | None] = 0

    def eval(self, p, th, kids):
        raise RuntimeError("macro slots are evaluated by the tree compiler")

    def bbox(self, v, kids):
        raise ValueError("a macro slot has no bounds of its own")


# ----------------------------------------------------------------------------------------------
# Files: nested JSON and the flat (pre-order) form
# ----------------------------------------------------------------------------------------------

def node_from_dict(d: object, path: str = "root", *, allow_slots: bool = False) -> Node:
    """Build a node tree from nested JSON data; errors name the node path."""
    if not isinstance(d, Mapping):
        raise ValueError(f"node {path}: expected an object with a 'node' field, got {type(d).__name__}")
    if allow_slots and "slot" in d:
        return SlotNode(size=int(d["slot"]), _dim=int(d.get("dim", 3)))
    if "node" not in d:
        raise ValueError(f"node {path}: missing the 'node' field (the node type)")
    unknown = set(d) - {"node", "params", "children", "size", "name"}
    if unknown:
        raise ValueError(f"node {path}: unknown field(s) {', '.join(sorted(unknown))}; "
                         "allowed: node, params, children, size, name")
    try:
        cls = node_type(str(d["node"]))
    except ValueError as e:
        raise ValueError(f"node {path}: {e}") from None
    raw_kids = d.get("children", [])
    if not isinstance(raw_kids, list):
        raise ValueError(f"node {path} ({cls.type_name}): 'children' must be a list")
    kids = tuple(node_from_dict(c, f"{path}/{i}", allow_slots=allow_slots) for i, c in enumerate(raw_kids))
    params = d.get("params", {})
    if not isinstance(params, Mapping):
        raise ValueError(f"node {path} ({cls.type_name}): 'params' must be an object of name: number")
    size = d.get("size")
    if cls.sized and size is None and params:
        size = cls.size_from_names(list(params)) if hasattr(cls, "size_from_names") else None
    try:
        check_children(cls, kids, size, path)
        return cls.from_values(dict(params), children=kids, size=size, name=d.get("name"))
    except ValueError as e:
        msg = str(e)
        raise ValueError(msg if msg.startswith("node ") else f"node {path} ({cls.type_name}): {msg}") from None


def node_to_dict(node: Node) -> dict:
    if isinstance(node, SlotNode):
        return {"slot": node.size}
    out: dict = {"node": node.type_name}
    if node.name:
        out["name"] = node.name
    if node.sized:
        out["size"] = node.size
    if node.values:
        out["params"] = {p.name: v for p, v in zip(node.param_defs(), node.values)}
    if node.children:
        out["children"] = [node_to_dict(c) for c in node.children]
    return out


def _token(node: Node) -> str:
    if node.sized:
        return f"{node.type_name}:{node.size}"
    if node.arity is None:
        return f"{node.type_name}:{len(node.children)}"
    return node.type_name


def to_flat(node: Node) -> dict:
    """The thesis's flat form: pre-order ``structure`` tokens and one flat ``params`` list.

    Tokens are node type names; a node with a size or a variable number of children is written
    ``type:k``. Discrete values sit in ``params`` like the others (as whole numbers).
    """
    structure, params = [], []
    for n, _ in _preorder(node):
        structure.append(_token(n))
        params.extend(n.values)
    return {"structure": structure, "params": params}


def from_flat(data: Mapping) -> Node:
    """Inverse of :func:`to_flat`; errors give the token position."""
    structure, params = data.get("structure"), data.get("params")
    if not isinstance(structure, list) or not isinstance(params, list):
        raise ValueError("flat tree: expected lists 'structure' and 'params'")
    pos = {"tok": 0, "par": 0}

    def build(path: str) -> Node:
        if pos["tok"] >= len(structure):
            raise ValueError(f"flat tree: structure ended early at node {path}")
        tok = str(structure[pos["tok"]])
        pos["tok"] += 1
        name, _, k = tok.partition(":")
        try:
            cls = node_type(name)
        except ValueError as e:
            raise ValueError(f"node {path}: {e}") from None
        if cls.arity is None and not k:
            raise ValueError(f"node {path} ({name}): variadic nodes are written '{name}:k' in the flat form")
        if k and not k.isdigit():
            raise ValueError(f"node {path} ({name}): expected a whole number after ':', got {tok!r}")
        size = int(k) if (k and cls.sized) else (cls.default_size if cls.sized else None)
        n_kids = int(k) if (k and cls.arity is None) else (cls.arity or 0)
        defs = cls.param_defs_for(size)
        vals = params[pos["par"]: pos["par"] + len(defs)]
        if len(vals) != len(defs):
            raise ValueError(f"flat tree: params ended early at node {path} ({name})")
        pos["par"] += len(defs)
        kids = tuple(build(f"{path}/{i}") for i in range(n_kids))
        try:
            return cls.make(*vals, children=kids, size=size)
        except ValueError as e:
            raise ValueError(f"node {path} ({name}): {e}") from None

    root = build("root")
    if pos["tok"] != len(structure) or pos["par"] != len(params):
        raise ValueError(f"flat tree: {len(structure) - pos['tok']} tokens and "
                         f"{len(params) - pos['par']} values left over after the root")
    return root


def tree_from_json(data: Mapping) -> Tree:
    """A tree from either file form: nested (``{"node": ...}``, optionally under ``"tree"``) or flat."""
    if not isinstance(data, Mapping):
        raise ValueError("tree file: expected a JSON object")
    if "structure" in data:
        return Tree(from_flat(data))
    if "tree" in data:
        data = data["tree"]
    return Tree(node_from_dict(data))


def tree_to_json(tree: Tree | Node, *, flat: bool = False) -> dict:
    root = tree.root if isinstance(tree, Tree) else tree
    return to_flat(root) if flat else {"tree": node_to_dict(root)}


def load_tree(path) -> Tree:
    """Read a tree file (nested or flat JSON); ``ValueError`` with a one-line reason on failure."""
    import json
    from pathlib import Path

    path = Path(path)
    if not path.is_file():
        raise ValueError(f"tree file not found: {path}")
    try:
        data = json.loads(path.read_text())
    except json.JSONDecodeError as e:
        raise ValueError(f"tree file {path} is not valid JSON: {e.msg} at line {e.lineno}") from None
    return tree_from_json(data)
