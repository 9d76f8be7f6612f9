"""Macro ("complex") nodes defined by data files.

A macro file gives the node's outer parameters, a subtree of ordinary nodes, and an expression graph
mapping outer parameters to the subtree's parameters::

    {"name": "table", "dim": 3, "doc": "...",
     "params": [{"name": "width", "default": 1.2, "lo": 0.2, "hi": 5.0}, ...],
     "defs":   {"half_w": {"mul": ["width", 0.5]}},          # optional shared sub-expressions
     "tree":   {"node": "translate", "params": {"y": "height"}, "children": [{"slot": 0}]}}

An expression is a number (a constant), a name (an outer parameter or a def), or one operation
``{"op": [args]}`` with op in const, neg, add, sub, mul, div, min, max. ``{"slot": i}`` in the tree
stands for the macro's i-th child (so macros can be transforms). Derivatives flow through the
expressions by the chain rule like through any node, because they are evaluated with torch.

The file's structure is checked before anything is built, each error naming the file and the key: the
keys are ``name`` (a non-empty string without ``:``), ``params`` (a list of objects with ``name``,
``default``, ``lo``, ``hi`` and optionally ``kind`` and ``doc``), ``tree`` (an object), and optionally
``doc`` (a string), ``dim`` (2 or 3), ``exact`` (true or false) and ``defs`` (an object of name:
expression); other keys are refused.

Macros may use other macros. A macro counts as one level and those of its body with the macros it uses
expanded (:attr:`MacroNode.levels`), and like a tree it may be at most :data:`ipm.tree.MAX_DEPTH` levels deep: a
chain of macros that would nest deeper (A uses B uses C ...) is refused when it is loaded, before anything
recurses through it, and so are macros that use each other in a circle.

Shipped macros live in ``ipm/sdf/library``; users add theirs with ``--library DIR``.
"""

from __future__ import annotations

import logging
import math
from collections.abc import Mapping
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import torch

from ipm.errors import InputError
from ipm.params import Param
from ipm.sdf.node import NODES, Node, SlotNode, check_children
from ipm.sdf.tree import expanded_depth, node_from_dict
from ipm.tree import MAX_DEPTH, check_depth, read_json

log = logging.getLogger(__name__)

LIBRARY_DIR = Path(__file__).parent / "library"
OPS = {"const": (1, 1), "neg": (1, 1), "add": (2, None), "sub": (2, 2), "mul": (2, None),
       "div": (2, 2), "min": (2, None), "max": (2, None)}
KEYS = ("name", "doc", "dim", "exact", "params", "defs", "tree")   # a macro file's keys
PARAM_KEYS = ("name", "default", "lo", "hi", "kind", "doc")       # the keys of each of its params


def _number(x) -> bool:
    return isinstance(x, (int, float)) and not isinstance(x, bool) and math.isfinite(x)


def check_spec(spec: object, where: str) -> None:
    """:class:`InputError` naming ``where`` (the file) and the key unless ``spec`` has a macro file's
    structure (the module docstring): the keys and the type of each; the expressions and the tree are
    checked when they are built (:func:`macro_type`)."""
    if not isinstance(spec, Mapping):
        raise InputError(f"{where}: expected a JSON object, got {type(spec).__name__}")
    unknown = sorted(str(k) for k in spec if k not in KEYS)
    if unknown:
        raise InputError(f"{where}: unknown key(s) {', '.join(map(repr, unknown))}; allowed: {', '.join(KEYS)}")
    for key in ("name", "params", "tree"):
        if key not in spec:
            raise InputError(f"{where}: missing the {key!r} field")
    name = spec["name"]
    if not isinstance(name, str) or not name or ":" in name:
        raise InputError(f"{where}: key 'name': expected a non-empty string without ':', got {name!r}")
    if not isinstance(spec.get("doc", ""), str):
        raise InputError(f"{where}: key 'doc': expected a string, got {spec['doc']!r}")
    if "dim" in spec and (isinstance(spec["dim"], bool) or spec["dim"] not in (2, 3)):
        raise InputError(f"{where}: key 'dim': expected 2 or 3, got {spec['dim']!r}")
    if not isinstance(spec.get("exact", False), bool):
        raise InputError(f"{where}: key 'exact': expected true or false, got {spec['exact']!r}")
    params = spec["params"]
    if not isinstance(params, list):
        raise InputError(f"{where}: key 'params': expected a list of parameters ({{name, default, lo, hi}}), "
                         f"got {type(params).__name__}")
    seen: set[str] = set()
    for i, p in enumerate(params):
        at = f"{where}: key 'params', entry {i}"
        if not isinstance(p, Mapping):
            raise InputError(f"{at}: expected an object with name, default, lo, hi, got {type(p).__name__}")
        bad = sorted(str(k) for k in p if k not in PARAM_KEYS)
        if bad:
            raise InputError(f"{at}: unknown key(s) {', '.join(map(repr, bad))}; allowed: {', '.join(PARAM_KEYS)}")
        if not isinstance(p.get("name"), str) or not p["name"]:
            raise InputError(f"{at}: key 'name': expected a non-empty string, got {p.get('name')!r}")
        at = f"{where}: parameter {p['name']!r}"
        if p["name"] in seen:
            raise InputError(f"{at}: expected unique parameter names, got {p['name']!r} twice")
        seen.add(p["name"])
        for key in ("default", "lo", "hi"):
            if key not in p:
                raise InputError(f"{at}: missing {key!r}; expected name, default, lo, hi")
            if not _number(p[key]):
                raise InputError(f"{at}: key {key!r}: expected a finite number, got {p[key]!r}")
        if p.get("kind", "float") not in ("float", "int", "bool"):
            raise InputError(f"{at}: key 'kind': expected float, int or bool, got {p['kind']!r}")
        if not isinstance(p.get("doc", ""), str):
            raise InputError(f"{at}: key 'doc': expected a string, got {p['doc']!r}")
    defs = spec.get("defs", {})
    if not isinstance(defs, Mapping):
        raise InputError(f"{where}: key 'defs': expected an object of name: expression, got {defs!r}")
    clash = sorted(seen & set(defs))
    if clash:
        raise InputError(f"{where}: key 'defs': expected names other than the parameters', got {', '.join(clash)}")
    if not isinstance(spec["tree"], Mapping):
        raise InputError(f"{where}: key 'tree': expected an object (a node), got {type(spec['tree']).__name__}")


def _check_expr(e: object, names: set[str], where: str) -> None:
    if isinstance(e, bool):
        raise InputError(f"{where}: expected a number, a name or an operation, got {e!r}")
    if isinstance(e, (int, float)):
        return
    if isinstance(e, str):
        if e not in names:
            raise InputError(f"{where}: unknown name {e!r}; known: {', '.join(sorted(names))}")
        return
    if isinstance(e, Mapping) and len(e) == 1:
        (op, args), = e.items()
        if op not in OPS:
            raise InputError(f"{where}: unknown operation {op!r}; allowed: {', '.join(OPS)}")
        args = args if isinstance(args, list) else [args]
        lo, hi = OPS[op]
        if len(args) < lo or (hi is not None and len(args) > hi):
            raise InputError(f"{where}: {op} takes {lo}{'' if hi == lo else '+' if hi is None else '-' + str(hi)} "
                             f"arguments, got {len(args)}")
        if op == "const" and not isinstance(args[0], (int, float)):
            raise InputError(f"{where}: expected a number after const, got {args[0]!r}")
        for a in args:
            _check_expr(a, names, where)
        return
    raise InputError(f"{where}: expected a number, a name or an operation, got {e!r}")


def _elementwise(torch_fn, py_fn):
    """A binary min/max that takes floats or 0-dim tensors (tensors win, in the tensor's dtype)."""

    def f(a, b):
        if torch.is_tensor(a) or torch.is_tensor(b):
            ref = a if torch.is_tensor(a) else b
            return torch_fn(torch.as_tensor(a, dtype=ref.dtype, device=ref.device),
                            torch.as_tensor(b, dtype=ref.dtype, device=ref.device))
        return py_fn(a, b)

    return f


_minimum = _elementwise(torch.minimum, min)
_maximum = _elementwise(torch.maximum, max)


def eval_expr(e, env: Mapping[str, object]):
    """Evaluate an expression over ``env`` (floats, ints or 0-dim tensors); differentiable in torch."""
    if isinstance(e, (int, float)):
        return e
    if isinstance(e, str):
        return env[e]
    (op, args), = e.items()
    args = args if isinstance(args, list) else [args]
    vals = [eval_expr(a, env) for a in args]
    if op == "const":
        return vals[0]
    if op == "neg":
        return -vals[0]
    if op == "sub":
        return vals[0] - vals[1]
    if op == "div":
        return vals[0] / vals[1]
    out = vals[0]
    combine = {"add": lambda a, b: a + b, "mul": lambda a, b: a * b, "min": _minimum, "max": _maximum}[op]
    for v in vals[1:]:
        out = combine(out, v)
    return out


class MacroNode(Node):
    """Base of the node types built from macro files (subclasses are made by :func:`macro_type`)."""

    template: Node
    exprs: tuple  # per template node in pre-order: tuple of (param index, expression)
    defs: tuple
    source: str
    # the tree levels the node stands for: itself and its body's with the macros it uses expanded
    # (ipm.sdf.tree counts them against the depth limit)
    levels: int = 1

    def _inner_values(self, th: tuple, like: torch.Tensor | None):
        env = {p.name: v for p, v in zip(self.params, th)}
        for name, e in self.defs:
            env[name] = eval_expr(e, env)
        return env

    def eval(self, p, th, kids):
        """The template evaluated with its parameters computed from this node's values (``defs``, then ``exprs``)."""
        env = self._inner_values(th, p)
        return _run(self.template, p, iter(self.exprs), env, kids)

    def bbox(self, v, kids):
        """The template's bounds with the parameters computed from this node's values."""
        env = self._inner_values(v, None)
        return _template_bbox(self.template, iter(self.exprs), env, kids)

    def expand(self) -> Node:
        """The template as an ordinary node tree: its values computed from this node's stored ones (floats, and
        rounded ints for discrete parameters; not checked against their bounds) and its slots replaced by this
        node's children. Used by whoever walks a tree node by node (exact meshes)."""
        env = self._inner_values(tuple(float(x) for x in self.values), None)
        return _expanded(self.template, iter(self.exprs), env, self.children)


def _node_values(node: Node, exprs: tuple, env, like: torch.Tensor | None) -> tuple:
    vals = list(node.values)
    for i, e in exprs:
        vals[i] = eval_expr(e, env)
    out = []
    for p, v in zip(node.param_defs(), vals):
        if not p.continuous:
            out.append(int(round(float(v))))
        elif like is not None and not torch.is_tensor(v):
            out.append(torch.tensor(float(v), dtype=like.dtype, device=like.device))
        elif like is not None:
            out.append(v.to(like.dtype))
        else:
            out.append(float(v))
    return tuple(out)


def _run(node: Node, p, exprs_it, env, slots) -> torch.Tensor:
    exprs = next(exprs_it)
    if isinstance(node, SlotNode):
        return slots[node.size](p)
    th = _node_values(node, exprs, env, p)
    kid_fns = []
    for c in node.children:
        # each child consumes its own part of the pre-order expression list, in order
        sub = [next(exprs_it) for _ in range(_count(c))]
        kid_fns.append(_closure(c, sub, env, slots))
    return node.eval(p, th, kid_fns)


def _closure(c, sub, env, slots):
    return lambda q: _run(c, q, iter(sub), env, slots)


def _count(node: Node) -> int:
    return 1 + sum(_count(c) for c in node.children)


def _expanded(node: Node, exprs_it, env, slot_nodes) -> Node:
    exprs = next(exprs_it)
    if isinstance(node, SlotNode):
        return slot_nodes[node.size]
    v = _node_values(node, exprs, env, None)
    kids = tuple(_expanded(c, exprs_it, env, slot_nodes) for c in node.children)
    return node.replace(values=v, children=kids)


def _template_bbox(node: Node, exprs_it, env, slot_boxes):
    exprs = next(exprs_it)
    if isinstance(node, SlotNode):
        return slot_boxes[node.size]
    v = _node_values(node, exprs, env, None)
    kids = [_template_bbox(c, exprs_it, env, slot_boxes) for c in node.children]
    lo, hi = node.bbox(v, kids)
    return np.asarray(lo, dtype=np.float64), np.asarray(hi, dtype=np.float64)


def _split_template(d: object, names: set[str], path: str, exprs: list) -> object:
    """Copy the template dict with expression-valued params removed (they are kept in ``exprs``)."""
    if not isinstance(d, Mapping) or "slot" in d:
        exprs.append(None)
        return d
    node_exprs = []
    exprs.append(node_exprs)
    out = dict(d)
    params = d.get("params", {})
    if not isinstance(params, Mapping):
        raise InputError(f"macro tree node {path}: expected 'params' as an object of name: number or expression, "
                         f"got {type(params).__name__}")
    nums = {}
    for k, e in params.items():
        if isinstance(e, (int, float)) and not isinstance(e, bool):
            nums[k] = e
        else:
            _check_expr(e, names, f"macro tree node {path}, parameter {k!r}")
            node_exprs.append((k, e))
    out["params"] = nums
    kids = d.get("children", [])
    if isinstance(kids, list):  # anything else is refused by node_from_dict
        out["children"] = [_split_template(c, names, f"{path}/{i}", exprs) for i, c in enumerate(kids)]
    return out


def _slots(node: Node) -> list[SlotNode]:
    if isinstance(node, SlotNode):
        return [node]
    return [s for c in node.children for s in _slots(c)]


def macro_type(spec: Mapping, source: str = "<memory>") -> type[Node]:
    """Build (not register) a node type from a macro definition; :class:`InputError` says what is wrong
    (:func:`check_spec` first: the structure; then the expressions, the tree and its depth with the macros
    it uses expanded, at most :data:`~ipm.tree.MAX_DEPTH` levels)."""
    where = f"macro file {source}"
    check_spec(spec, where)
    name = spec["name"]
    try:
        params = tuple(Param(p["name"], p["default"], p["lo"], p["hi"], p.get("kind", "float"), p.get("doc", ""))
                       for p in spec["params"])
    except InputError as e:
        raise InputError(f"{where}: {e}") from None
    names = {p.name for p in params}
    defs = []
    try:
        check_depth(spec["tree"])
    except InputError as e:
        raise InputError(f"{where}: key 'tree': {e}") from None
    for dname, e in spec.get("defs", {}).items():
        _check_expr(e, names, f"{where}, def {dname!r}")
        names.add(dname)
        defs.append((dname, e))
    raw_exprs: list = []
    try:
        tmpl_dict = _split_template(spec["tree"], names, "root", raw_exprs)
    except InputError as e:
        raise InputError(f"{where}: {e}") from None
    try:
        template = node_from_dict(tmpl_dict, allow_slots=True)
    except InputError as e:
        raise InputError(f"{where}: {e}") from None
    # Resolve parameter names of expression-valued entries to indices, in pre-order.
    flat_nodes = []

    def walk(n: Node):
        flat_nodes.append(n)
        for c in n.children:
            walk(c)

    walk(template)
    exprs = []
    for n, ne in zip(flat_nodes, raw_exprs):
        if ne is None or isinstance(n, SlotNode):
            exprs.append(())
            continue
        idx = {p.name: i for i, p in enumerate(n.param_defs())}
        resolved = []
        for k, e in ne:
            if k not in idx:
                raise InputError(f"{where}: node {n.type_name} has no parameter {k!r}; "
                                 f"valid: {', '.join(idx)}")
            if not n.param_defs()[idx[k]].continuous and _uses_continuous(e, params, defs):
                raise InputError(f"{where}: discrete parameter {n.type_name}.{k} depends on a "
                                 "continuous parameter")
            resolved.append((idx[k], e))
        exprs.append(tuple(resolved))
    slots = _slots(template)
    arity = len({s.size for s in slots})
    if sorted({s.size for s in slots}) != list(range(arity)):
        raise InputError(f"{where}: expected slots numbered 0 .. k-1, got {sorted({s.size for s in slots})}")
    dim = spec.get("dim", template.out_dim)
    if dim != template.out_dim:
        raise InputError(f"{where}: expected a {dim}D tree (the declared dim), got a {template.out_dim}D tree")
    levels, via = expanded_depth(template)
    levels += 1  # the macro node itself: its evaluation and bounds recurse through it into the body
    if levels > MAX_DEPTH:
        raise InputError(f"{where}: expected a macro at most {MAX_DEPTH} levels deep with the macros it uses "
                         f"expanded (the limit), got {levels} levels"
                         + (f" (it uses {via.type_name}, {via.levels} levels deep)" if via is not None else ""))
    attrs = {
        "type_name": name, "dim": dim, "arity": arity, "levels": levels,
        "child_dim": (slots[0].out_dim if slots else None), "exact": bool(spec.get("exact", False)),
        "params": params, "template": template, "exprs": tuple(exprs), "defs": tuple(defs),
        "source": source, "spec": dict(spec), "__doc__": spec.get("doc", f"Macro node {name} from {source}."),
    }
    cls = type(f"Macro_{name}", (MacroNode,), attrs)
    return dataclass(frozen=True, eq=False)(cls)


def _uses_continuous(e, params, defs) -> bool:
    cont = {p.name for p in params if p.continuous}
    dmap = dict(defs)

    def uses(x) -> bool:
        if isinstance(x, str):
            return x in cont or (x in dmap and uses(dmap[x]))
        if isinstance(x, Mapping):
            (_, args), = x.items()
            return any(uses(a) for a in (args if isinstance(args, list) else [args]))
        return False

    return uses(e)


def load_library(dirs: list[Path | str] | None = None) -> list[str]:
    """Register every ``*.json`` macro in the shipped library and in ``dirs``; return the new names.

    Files may use macros from other files: they are built in the order of their use (a macro after the
    ones it uses). A file that repeats a registered macro to the letter (a copy of a shipped one) is
    accepted; a different definition under a registered name is an :class:`InputError` naming the file
    and the node, and so are files that use each other in a circle and chains of macros deeper than
    :data:`~ipm.tree.MAX_DEPTH` levels (see the module docstring). Every file's structure is checked
    before any is built, and on an error none of the macros this call added stays registered.
    """
    paths = sorted(LIBRARY_DIR.glob("*.json"))
    for d in dirs or []:
        d = Path(d)
        if not d.is_dir():
            raise InputError(f"expected a macro library folder, got {d} (not found)")
        paths += sorted(d.glob("*.json"))
    specs = {path: _read_macro(path) for path in paths}
    todo: dict[str, Path] = {}  # the new macros by name
    for path, spec in specs.items():
        first = todo.get(spec["name"])
        if first is not None:
            if specs[first] == spec:
                continue
            raise InputError(f"macro file {path}: expected a new node name or the same definition as {first}, "
                             f"got a different definition of node {spec['name']!r}")
        if not _known(spec, path):
            todo[spec["name"]] = path
    added: list[str] = []
    try:
        for name in _build_order({n: specs[p] for n, p in todo.items()}, todo):
            cls = macro_type(specs[todo[name]], str(todo[name]))
            NODES.add(cls.type_name, cls)
            added.append(cls.type_name)
    except BaseException:
        for name in added:
            NODES.remove(name)
        raise
    return added


def _uses(tree: object) -> set[str]:
    """The node type names a macro body uses (without recursion)."""
    out, stack = set(), [tree]
    while stack:
        d = stack.pop()
        if not isinstance(d, Mapping):
            continue
        if isinstance(d.get("node"), str):
            out.add(d["node"])
        if isinstance(d.get("children"), list):
            stack.extend(d["children"])
    return out


def _build_order(specs: Mapping[str, Mapping], paths: Mapping[str, Path]) -> list[str]:
    """The names of ``specs`` (new macros, their files ``paths``) ordered so that each comes after the new
    macros it uses, else in the order of the files; :class:`InputError` for macros using each other in a
    circle."""
    deps = {n: _uses(s["tree"]) & set(specs) for n, s in specs.items()}
    users: dict[str, list[str]] = {n: [] for n in specs}
    for n, ds in deps.items():
        for d in ds:
            users[d].append(n)
    waiting = {n: len(ds) for n, ds in deps.items()}
    ready = [n for n in specs if waiting[n] == 0][::-1]  # a stack, the first file on top
    order: list[str] = []
    while ready:
        n = ready.pop()
        order.append(n)
        for u in users[n]:
            waiting[u] -= 1
            if waiting[u] == 0:
                ready.append(u)
    if len(order) < len(specs):
        done = set(order)
        n = next(m for m in specs if m not in done)
        circle: list[str] = []
        while n not in circle:  # every macro left waits for one that is left
            circle.append(n)
            n = min(d for d in deps[n] if d not in done)
        circle = circle[circle.index(n):] + [n]
        raise InputError(f"macro file {paths[circle[0]]}: expected macros that do not use themselves, got a "
                         f"circle: {' uses '.join(circle)}")
    return order


def _read_macro(path: Path) -> dict:
    spec = read_json(path, "macro file")
    check_spec(spec, f"macro file {path}")
    return spec


def _known(spec: Mapping, path: Path) -> bool:
    """True if ``spec`` is already registered as it is; InputError if its name is taken by another node."""
    name = spec.get("name")
    if not isinstance(name, str) or name not in NODES:
        return False
    old = NODES.get(name)
    if getattr(old, "spec", None) == spec:
        return True
    where = getattr(old, "source", None) or f"the built-in node {old.__module__}.{old.__qualname__}"
    raise InputError(f"macro file {path}: expected a new node name or the same definition as {where}, "
                     f"got a different definition of node {name!r}")


__all__ = ["check_spec", "macro_type", "load_library", "eval_expr", "MacroNode", "check_children"]
