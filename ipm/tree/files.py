"""Tree files: nested JSON (``{"node": type, "name": ..., "size": ..., "params": {...}, "children": [...]}``)
and the flat form (pre-order ``structure`` tokens and one ``params`` list), read within the depth limit."""

from __future__ import annotations

from collections.abc import Callable, Mapping
from pathlib import Path

from ipm import files
from ipm.errors import InputError
from ipm.registry import Registry
from ipm.tree.node import TreeNode
from ipm.tree.walk import MAX_DEPTH, depth_error, preorder

FIELDS = ("node", "params", "children", "size", "name")


def check_depth(data: object) -> None:
    """Refuse nested JSON deeper than ``MAX_DEPTH`` (before anything recurses into it)."""
    stack = [(data, 1)]
    while stack:
        d, depth = stack.pop()
        if depth > MAX_DEPTH:
            raise depth_error(depth)
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
            raise depth_error(depth)
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


def read_json(path: str | Path, what: str) -> object:
    """A JSON file's data (:func:`ipm.files.read_json`); files nesting deeper than a tree of
    ``MAX_DEPTH`` levels can (an object and a list per level) are refused before the JSON parser
    recurses into them."""
    return files.read_json(path, what, max_nesting=2 * MAX_DEPTH + 4,
                           too_deep=f"expected a tree at most {MAX_DEPTH} levels deep (the limit)")


__all__ = ["FIELDS", "check_depth", "from_flat", "node_from_dict", "read_json", "to_flat"]
