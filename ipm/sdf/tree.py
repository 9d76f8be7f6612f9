"""SDF trees: a validated node tree compiled to one torch function of ``(theta, points)``, and its files.

:class:`Tree` flattens an instance tree (:mod:`ipm.tree`) into one :class:`~ipm.params.ParamSpec` and
evaluates it for any parameter vector ``theta``. Files are nested JSON (optionally under ``"tree"``) or
the flat form.
"""

from __future__ import annotations

from collections.abc import Callable, Mapping

import numpy as np
import torch

from ipm import tree as T
from ipm.errors import InputError
from ipm.sdf._math import coord_major
from ipm.sdf.node import NODES, Box, Eval, Node, SlotNode

EVAL_CHUNK = 1 << 18


class Tree:
    """A validated tree of SDF nodes with a flat parameter vector.

    ``spec`` lists every parameter as ``<label>.<param>`` (label: the node's ``name`` or
    ``n<preorder index>_<type>``). ``theta`` holds the continuous ones in that order; discrete ones
    (counts, axes) are baked into the nodes and changed with :meth:`with_values`.
    """

    def __init__(self, root: Node, *, dim: int = 3):
        if not isinstance(root, Node):
            raise InputError(f"expected an SDF node as the tree root, got {type(root).__name__}")
        if root.out_dim != dim and dim == 3:
            raise InputError(f"node root ({root.type_name}): the root must be a 3D node, got a 2D node; "
                             "lift 2D shapes with extrude or revolve")
        if root.out_dim != dim:
            raise InputError(f"node root ({root.type_name}): expected a {dim}D node, got a {root.out_dim}D node")
        self.root = root
        self.dim = dim
        visits = T.preorder(root)
        depth, via = expanded_depth(root)
        if depth > T.MAX_DEPTH:
            raise InputError(f"expected a tree at most {T.MAX_DEPTH} levels deep with its macro nodes expanded "
                             f"(the limit), got {depth} levels" + (f" (through the macro {via.type_name}, "
                                                                   f"{via.levels} levels deep)" if via else ""))
        self.nodes: list[tuple[Node, str]] = [(v.node, v.path) for v in visits]
        self.spec, _, self._offsets = T.flat_spec(visits)
        self._fn = _compile(root, iter(range(len(visits))), self._offsets)

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
        """Every parameter's stored value by name (the tree's spec keeps them as its defaults)."""
        return self.spec.defaults()

    def sdf(self, theta: torch.Tensor | None, points: torch.Tensor) -> torch.Tensor:
        """Signed distance ``(...)`` at ``points: (..., dim)`` for ``theta: (n,)`` (None: stored values).

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
        return Tree(T.rebuild(self.root, iter(full[p.name] for p in self.spec.params)), dim=self.dim)

    def with_theta(self, theta: torch.Tensor) -> Tree:
        """A new tree storing ``theta: (n,)`` as its continuous values."""
        vals = theta.detach().cpu().double().tolist()
        if len(vals) != self.n_params:
            raise InputError(f"expected theta of length {self.n_params}, got {len(vals)}")
        return self.with_values(dict(zip((p.name for p in self.spec.continuous), vals)))

    def bounds(self) -> Box:
        """Conservative bounding box ``(lo (3,), hi (3,))`` of the solid at the stored values."""
        return _bbox(self.root)


def _bbox(node: Node) -> Box:
    kids = [_bbox(c) for c in node.children]
    lo, hi = node.bbox(tuple(float(v) for v in node.values), kids)
    return np.asarray(lo, dtype=np.float64), np.asarray(hi, dtype=np.float64)


def _compile(node: Node, counter, offsets) -> Callable:
    """Turn an instance tree into ``f(points, theta, slots) -> distances``."""
    off = offsets[next(counter)]
    # For each parameter: ("c", position in theta) or ("d", python int value).
    getters: list[tuple[str, object]] = []
    k = off
    for p, v in zip(node.param_defs(), node.values):
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


# ----------------------------------------------------------------------------------------------
# Files
# ----------------------------------------------------------------------------------------------

def expanded_depth(root: Node) -> tuple[int, Node | None]:
    """``(levels, macro)``: how many levels deep ``root``'s tree is with its macro nodes expanded (a macro
    node counts as its ``levels``, an other node as one; without recursion), and the macro node that
    adds the most levels on the deepest path (None if none does)."""
    deepest, via = 0, None
    stack: list[tuple[Node, int, Node | None]] = [(root, 0, None)]
    while stack:
        node, above, macro = stack.pop()
        levels = getattr(type(node), "levels", 1)
        if levels > 1 and (macro is None or levels > macro.levels):
            macro = node
        depth = above + levels
        if depth > deepest:
            deepest, via = depth, macro
        stack.extend((c, depth, macro) for c in node.children)
    return deepest, via


def _slot(d: Mapping) -> Node | None:
    if "slot" not in d:
        return None
    unknown = sorted(str(k) for k in d if k not in ("slot", "dim"))
    if unknown:
        raise InputError(f"macro slot {d['slot']!r}: unknown key(s) {', '.join(unknown)}; allowed: slot, dim")
    size, dim = d["slot"], d.get("dim", 3)
    if isinstance(size, bool) or not isinstance(size, int) or not 0 <= size < 1000:
        raise InputError(f"macro slot: expected a child's number from 0 to 999, got {size!r}")
    if isinstance(dim, bool) or dim not in (2, 3):
        raise InputError(f"macro slot {size}: key 'dim': expected 2 or 3, got {dim!r}")
    return SlotNode(size=size, _dim=dim)


def node_from_dict(d: object, path: str = "root", *, allow_slots: bool = False) -> Node:
    """A node tree from nested JSON data; errors name the node path (``allow_slots``: macro bodies)."""
    return T.node_from_dict(d, NODES, path, special=_slot if allow_slots else None)


def node_to_dict(node: Node) -> dict:
    """The nested JSON form of a node tree."""
    return node.to_dict()


def to_flat(node: Node) -> dict:
    """The thesis's flat form (see :func:`ipm.tree.to_flat`)."""
    return T.to_flat(node)


def from_flat(data: Mapping) -> Node:
    """Inverse of :func:`to_flat`; errors give the token position."""
    return T.from_flat(data, NODES)


def tree_from_json(data: Mapping, dim: int | None = 3) -> Tree:
    """A tree from either file form: nested (``{"node": ...}``, optionally under ``"tree"``) or flat; its
    root ``dim``-dimensional (None: either, a 2D tree for 2D fits)."""
    if not isinstance(data, Mapping):
        raise InputError(f"tree file: expected a JSON object, got {type(data).__name__}")
    if "structure" in data:
        root = from_flat(data)
    else:
        root = node_from_dict(data["tree"] if "tree" in data else data)
    return Tree(root, dim=root.out_dim if dim is None else dim)


def tree_to_json(tree: Tree | Node, *, flat: bool = False) -> dict:
    """``{"tree": nested}`` or the flat form of a tree or node."""
    root = tree.root if isinstance(tree, Tree) else tree
    return to_flat(root) if flat else {"tree": node_to_dict(root)}


def load_tree(path, dim: int | None = 3) -> Tree:
    """Read a tree file (nested or flat JSON; ``dim``: see :func:`tree_from_json`); :class:`InputError` with
    a one-line reason on failure, naming the file."""
    data = T.read_json(path, "tree file")
    try:
        return tree_from_json(data, dim)
    except InputError as e:
        msg = str(e).removeprefix("tree file: ")
        raise InputError(msg if str(path) in msg else f"tree file {path}: {msg}") from None


__all__ = ["EVAL_CHUNK", "Tree", "expanded_depth", "from_flat", "load_tree", "node_from_dict", "node_to_dict",
           "to_flat", "tree_from_json", "tree_to_json"]
