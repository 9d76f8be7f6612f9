"""One tree framework for SDF trees (:mod:`ipm.sdf`) and mesh trees (:mod:`ipm.generators.meshtree`).

A node *type* is a subclass of :class:`TreeNode` that declares its registry name, how many children it
takes and its named, bounded parameters; it registers itself in its family's
:class:`~ipm.registry.Registry` (one file per topic in the family's node package, found by package
discovery). A node *instance* is frozen data: its parameter values in declaration order, its children,
its size (sized nodes: the number of polygon or profile points) and an optional name (its label).

Trees flatten in pre-order into one :class:`~ipm.params.ParamSpec` whose names are
``<label>.<param>`` (label: the node's ``name`` or ``n<preorder index>_<type>``). Files are nested
JSON (``{"node": type, "name": ..., "size": ..., "params": {...}, "children": [...]}``) or the flat
form (pre-order ``structure`` tokens and one ``params`` list).

Trees are at most :data:`MAX_DEPTH` levels deep: deeper input is refused with an
:class:`~ipm.errors.InputError` before anything recurses (evaluation nests a few Python frames per level).
"""

from __future__ import annotations

import json
import operator
import re
from collections.abc import Callable, Iterator, Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import ClassVar

from ipm.errors import InputError
from ipm.params import Param, ParamSpec
from ipm.registry import Registry

MAX_DEPTH = 64
FIELDS = ("node", "params", "children", "size", "name")


def _depth_error(depth: int) -> InputError:
    return InputError(f"expected a tree at most {MAX_DEPTH} levels deep (the limit), got {depth} or more")


@dataclass(frozen=True, eq=False)
class TreeNode:
    """A node instance: immutable values and children.

    Class attributes (set by each node type):
      type_name: registry key; arity: number of children, or ``None`` for at least ``min_children``;
      params: the parameter declarations; ``size_prefix`` (non-empty for sized nodes, whose parameters
      depend on ``size``: ``params`` then :meth:`point_params` per point) names the per-point parameter
      counted to infer the size from a file's parameter names; ``default_size``, ``min_size``.
      ``sized`` is derived: True when ``size_prefix`` is set.
    """

    values: tuple = ()
    children: tuple[TreeNode, ...] = ()
    size: int | None = None
    name: str | None = None

    type_name: ClassVar[str] = ""
    arity: ClassVar[int | None] = 0
    min_children: ClassVar[int] = 2
    params: ClassVar[tuple[Param, ...]] = ()
    sized: ClassVar[bool] = False
    default_size: ClassVar[int | None] = None
    min_size: ClassVar[int] = 1
    size_prefix: ClassVar[str] = ""

    def __init_subclass__(cls, **kwargs):
        super().__init_subclass__(**kwargs)
        cls.sized = bool(cls.size_prefix)

    # -- declarations ---------------------------------------------------------------------------
    @classmethod
    def param_defs_for(cls, size: int | None) -> tuple[Param, ...]:
        """Parameter declarations of an instance of the given size: ``params``, then for sized nodes
        the parameters of each point (:meth:`point_params`)."""
        if not cls.sized:
            return cls.params
        k = cls.default_size if size is None else size
        return cls.params + tuple(q for i in range(k) for q in cls.point_params(i, k))

    @classmethod
    def point_params(cls, i: int, k: int) -> tuple[Param, ...]:
        """Sized nodes: the parameters of point ``i`` of ``k`` (``x{i}``, ``y{i}``, ...)."""
        return ()

    def param_defs(self) -> tuple[Param, ...]:
        return type(self).param_defs_for(self.size)

    @classmethod
    def size_from_names(cls, names: Sequence[str]) -> int | None:
        """The size implied by parameter names (how many ``<size_prefix><i>`` there are)."""
        pre = cls.size_prefix
        if not pre:
            return None
        return sum(1 for n in names if n.startswith(pre) and n[len(pre):].isdigit()) or None

    @classmethod
    def check_size(cls, size: object) -> int | None:
        """The validated size: None for unsized types, the default when omitted."""
        if not cls.sized:
            if size is not None:
                raise InputError(f"{cls.type_name}: expected no size, got {size!r}")
            return None
        size = cls.default_size if size is None else size
        if isinstance(size, float) and size.is_integer():
            size = int(size)
        try:
            k = None if isinstance(size, bool) else operator.index(size)  # ints and NumPy ints
        except TypeError:
            k = None
        if k is None or k < cls.min_size:
            raise InputError(f"{cls.type_name}: expected size >= {cls.min_size}, got {size!r}")
        return k

    # -- construction ---------------------------------------------------------------------------
    @classmethod
    def make(cls, *args, children: Sequence[TreeNode] = (), size: int | None = None,
             name: str | None = None, **kwargs) -> TreeNode:
        """Build an instance: positional values (sequences are flattened) then keyword values.

        Missing values take their defaults; values are checked against the declared bounds.
        """
        size = cls.check_size(size)
        defs = cls.param_defs_for(size)
        flat: list = []
        for a in args:
            if hasattr(a, "tolist") and getattr(a, "ndim", 0) > 0:
                flat.extend(float(x) for x in a.tolist())
            elif isinstance(a, (list, tuple)):
                flat.extend(float(x) for x in a)
            else:
                flat.append(a)
        if len(flat) > len(defs):
            raise InputError(f"{cls.type_name}: expected at most {len(defs)} values "
                             f"({', '.join(p.name for p in defs)}), got {len(flat)}")
        given = {p.name: v for p, v in zip(defs, flat)}
        for k, v in kwargs.items():
            if k in given:
                raise InputError(f"{cls.type_name}: expected one value for {k!r}, got two")
            given[k] = v
        return cls.from_values(given, children=children, size=size, name=name)

    @classmethod
    def from_values(cls, given: Mapping[str, object], *, children: Sequence[TreeNode] = (),
                    size: int | None = None, name: str | None = None) -> TreeNode:
        """Build an instance from named values (missing ones take their defaults), checking bounds."""
        size = cls.check_size(size)
        defs = cls.param_defs_for(size)
        try:
            values = ParamSpec(defs).validate(given)
        except InputError:
            raise
        except ValueError as e:
            raise InputError(str(e)) from None
        return cls._new(tuple(values[p.name] for p in defs), tuple(children), size, name)

    @classmethod
    def _new(cls, values: tuple, children: tuple, size: int | None, name: str | None) -> TreeNode:
        kids = tuple(children)
        cls.check_children(kids)
        node = cls(values=tuple(values), children=kids, size=size, name=name, **cls.derived_fields(kids))
        node.check()
        return node

    @classmethod
    def derived_fields(cls, kids: tuple[TreeNode, ...]) -> dict:
        """Extra dataclass fields computed from the children (SDF nodes: their dimension)."""
        return {}

    @classmethod
    def check_children(cls, kids: tuple[TreeNode, ...], path: str = "root") -> None:
        """Arity rules (and the family's own, :meth:`check_child_kinds`); errors name the node's path."""
        label = f"node {path} ({cls.type_name})"
        if cls.arity is None:
            if len(kids) < cls.min_children:
                raise InputError(f"{label}: expected at least {cls.min_children} "
                                 f"child{'ren' if cls.min_children != 1 else ''}, got {len(kids)}")
        elif len(kids) != cls.arity:
            raise InputError(f"{label}: expected {cls.arity} child{'ren' if cls.arity != 1 else ''}, "
                             f"got {len(kids)}")
        cls.check_child_kinds(kids, label)

    @classmethod
    def check_child_kinds(cls, kids: tuple[TreeNode, ...], label: str) -> None:
        """Family rules on the children (SDF: dimensions); raise :class:`InputError`."""

    def check(self) -> None:
        """Extra validation of the stored values; raise :class:`InputError`."""

    def replace(self, *, values: tuple | None = None, children: tuple | None = None) -> TreeNode:
        """A copy with new values (declaration order) and/or children."""
        return type(self)._new(self.values if values is None else values,
                               self.children if children is None else children, self.size, self.name)

    # -- files ----------------------------------------------------------------------------------
    def to_dict(self) -> dict:
        """The nested JSON form of this subtree."""
        out: dict = {"node": self.type_name}
        if self.name:
            out["name"] = self.name
        if self.sized:
            out["size"] = self.size
        if self.values:
            out["params"] = {p.name: v for p, v in zip(self.param_defs(), self.values)}
        if self.children:
            out["children"] = [c.to_dict() for c in self.children]
        return out

    def token(self) -> str:
        """This node's token in the flat form: ``type``, or ``type:k`` for sized and variadic nodes."""
        if self.sized:
            return f"{self.type_name}:{self.size}"
        if self.arity is None:
            return f"{self.type_name}:{len(self.children)}"
        return self.type_name


# ----------------------------------------------------------------------------------------------
# Pre-order walks and the flat parameter vector
# ----------------------------------------------------------------------------------------------

@dataclass(frozen=True)
class Visit:
    """One node of a pre-order walk: the node, its parent's pre-order index (-1 at the root) and its
    path (``root/0/2``)."""

    node: TreeNode
    parent: int
    path: str


def preorder(root: TreeNode) -> list[Visit]:
    """The nodes of a tree in pre-order, without recursion; :class:`InputError` beyond ``MAX_DEPTH``."""
    out: list[Visit] = []
    stack = [(root, -1, "root", 1)]
    while stack:
        node, parent, path, depth = stack.pop()
        if depth > MAX_DEPTH:
            raise _depth_error(depth)
        me = len(out)
        out.append(Visit(node, parent, path))
        for i in reversed(range(len(node.children))):
            stack.append((node.children[i], me, f"{path}/{i}", depth + 1))
    return out


def node_label(node: TreeNode, index: int) -> str:
    """A node's label: its name, else ``n<preorder index>_<type>``."""
    return node.name or f"n{index}_{node.type_name}"


def flat_spec(visits: Sequence[Visit]) -> tuple[ParamSpec, list[str], list[int]]:
    """``(spec, labels, offsets)``: the tree's parameters named ``<label>.<param>`` in pre-order, the
    labels, and each node's offset into ``theta`` (continuous parameters only)."""
    params, labels, offsets, off = [], [], [], 0
    for i, v in enumerate(visits):
        label = node_label(v.node, i)
        labels.append(label)
        offsets.append(off)
        for p, val in zip(v.node.param_defs(), v.node.values):
            params.append(Param(f"{label}.{p.name}", val, p.lo, p.hi, p.kind, p.doc))
            off += p.continuous
    if len(set(labels)) != len(labels):
        dup = sorted({x for x in labels if labels.count(x) > 1})
        raise InputError(f"tree: node names must be unique, got {', '.join(dup)} more than once")
    return ParamSpec(tuple(params)), labels, offsets


def rebuild(root: TreeNode, values: Iterator) -> TreeNode:
    """The tree with every node's values taken, in pre-order, from ``values``."""
    vals = tuple(next(values) for _ in root.param_defs())
    kids = tuple(rebuild(c, values) for c in root.children)
    return root.replace(values=vals, children=kids)


def same_tree(a: TreeNode, b: TreeNode) -> bool:
    """Structural equality: same types, sizes, names, values and children."""
    return type(a) is type(b) and a.to_dict() == b.to_dict()


# ----------------------------------------------------------------------------------------------
# Files: nested JSON and the flat (pre-order) form
# ----------------------------------------------------------------------------------------------

def check_depth(data: object) -> None:
    """Refuse nested JSON deeper than ``MAX_DEPTH`` (before anything recurses into it)."""
    stack = [(data, 1)]
    while stack:
        d, depth = stack.pop()
        if depth > MAX_DEPTH:
            raise _depth_error(depth)
        kids = d.get("children") if isinstance(d, Mapping) else None
        if isinstance(kids, list):
            stack.extend((c, depth + 1) for c in kids)


Special = Callable[[Mapping], TreeNode | None]


def node_from_dict(data: object, registry: Registry, path: str = "root", *,
                   special: Special | None = None) -> TreeNode:
    """A node tree from nested JSON data; errors name the node path.

    special: builds nodes that are not registered types (macro slots) from their dict, or None.
    """
    check_depth(data)
    return _from_dict(data, registry, path, special)


def _from_dict(d: object, registry: Registry, path: str, special: Special | None) -> TreeNode:
    if not isinstance(d, Mapping):
        raise InputError(f"node {path}: expected an object with a 'node' field, got {type(d).__name__}")
    if special is not None:
        node = special(d)
        if node is not None:
            return node
    if "node" not in d:
        raise InputError(f"node {path}: expected a 'node' field (the node type), got none")
    unknown = set(d) - set(FIELDS)
    if unknown:
        raise InputError(f"node {path}: unknown field(s) {', '.join(sorted(unknown))}; "
                         f"allowed: {', '.join(FIELDS)}")
    try:
        cls = registry.get(str(d["node"]))
    except InputError as e:
        raise InputError(f"node {path}: {e}") from None
    raw_kids = d.get("children", [])
    if not isinstance(raw_kids, list):
        raise InputError(f"node {path} ({cls.type_name}): expected a list of children, got "
                         f"{type(raw_kids).__name__}")
    kids = tuple(_from_dict(c, registry, f"{path}/{i}", special) for i, c in enumerate(raw_kids))
    params = d.get("params", {})
    if not isinstance(params, Mapping):
        raise InputError(f"node {path} ({cls.type_name}): expected 'params' as an object of name: number, "
                         f"got {type(params).__name__}")
    size = d.get("size")
    if cls.sized and size is None and params:
        size = cls.size_from_names(list(params))
    try:
        cls.check_children(kids, path)
        return cls.from_values(dict(params), children=kids, size=size, name=d.get("name"))
    except InputError as e:
        msg = str(e)
        raise InputError(msg if msg.startswith("node ") else f"node {path} ({cls.type_name}): {msg}") from None


def to_flat(root: TreeNode) -> dict:
    """The flat form: pre-order ``structure`` tokens (:meth:`TreeNode.token`) and one ``params`` list
    (discrete values sit there like the others, as whole numbers)."""
    structure, params = [], []
    for v in preorder(root):
        structure.append(v.node.token())
        params.extend(v.node.values)
    return {"structure": structure, "params": params}


def from_flat(data: Mapping, registry: Registry) -> TreeNode:
    """Inverse of :func:`to_flat`; errors give the token position."""
    structure, params = data.get("structure"), data.get("params")
    if not isinstance(structure, list) or not isinstance(params, list):
        raise InputError("flat tree: expected lists 'structure' and 'params', got "
                         f"{type(structure).__name__} and {type(params).__name__}")
    pos = {"tok": 0, "par": 0}

    def build(path: str, depth: int) -> TreeNode:
        if depth > MAX_DEPTH:
            raise _depth_error(depth)
        if pos["tok"] >= len(structure):
            raise InputError(f"flat tree: structure ended early at node {path}")
        tok = str(structure[pos["tok"]])
        pos["tok"] += 1
        name, _, k = tok.partition(":")
        try:
            cls = registry.get(name)
        except InputError as e:
            raise InputError(f"node {path}: {e}") from None
        if cls.arity is None and not k:
            raise InputError(f"node {path} ({name}): variadic nodes are written '{name}:k' in the flat form")
        if k and not k.isdigit():
            raise InputError(f"node {path} ({name}): expected a whole number after ':', got {tok!r}")
        size = int(k) if (k and cls.sized) else (cls.default_size if cls.sized else None)
        n_kids = int(k) if (k and cls.arity is None) else (cls.arity or 0)
        defs = cls.param_defs_for(size)
        vals = params[pos["par"]: pos["par"] + len(defs)]
        if len(vals) != len(defs):
            raise InputError(f"flat tree: params ended early at node {path} ({name})")
        pos["par"] += len(defs)
        kids = tuple(build(f"{path}/{i}", depth + 1) for i in range(n_kids))
        try:
            return cls.make(*vals, children=kids, size=size)
        except InputError as e:
            msg = str(e)
            raise InputError(msg if msg.startswith("node ") else f"node {path} ({name}): {msg}") from None

    root = build("root", 1)
    if pos["tok"] != len(structure) or pos["par"] != len(params):
        raise InputError(f"flat tree: {len(structure) - pos['tok']} tokens and "
                         f"{len(params) - pos['par']} values left over after the root")
    return root


def json_nesting(text: str) -> int:
    """How deeply objects and arrays nest in JSON ``text`` (strings skipped), without parsing it."""
    depth = deepest = 0
    for m in _BRACKETS.finditer(_STRINGS.sub('""', text)):
        depth += 1 if m.group() in "[{" else -1
        deepest = max(deepest, depth)
    return deepest


_STRINGS = re.compile(r'"(?:\\.|[^"\\])*"')
_BRACKETS = re.compile(r"[\[\]{}]")


def read_json(path: str | Path, what: str) -> object:
    """A JSON file's data; :class:`InputError` names ``what`` (e.g. "tree file") and the problem.

    Files nesting deeper than a tree of ``MAX_DEPTH`` levels can (an object and a list per level) are
    refused before the JSON parser recurses into them."""
    path = Path(path)
    if not path.is_file():
        raise InputError(f"{what} not found: {path}")
    text = path.read_text()
    nesting = json_nesting(text)
    if nesting > 2 * MAX_DEPTH + 4:
        raise InputError(f"{what} {path}: expected a tree at most {MAX_DEPTH} levels deep (the limit), "
                         f"got JSON nested {nesting} deep")
    try:
        return json.loads(text)
    except json.JSONDecodeError as e:
        raise InputError(f"{what} {path} is not valid JSON: {e.msg} at line {e.lineno}") from None


__all__ = ["MAX_DEPTH", "TreeNode", "Visit", "check_depth", "flat_spec", "from_flat", "node_from_dict",
           "node_label", "preorder", "json_nesting", "read_json", "rebuild", "same_tree", "to_flat"]
