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

Shipped macros live in ``ipm/sdf/library``; users add theirs with ``--library DIR``.
"""

from __future__ import annotations

import logging
from collections.abc import Mapping
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import torch

from ipm.errors import InputError
from ipm.params import Param
from ipm.sdf.node import NODES, Node, SlotNode, check_children
from ipm.sdf.tree import node_from_dict
from ipm.tree import read_json

log = logging.getLogger(__name__)

LIBRARY_DIR = Path(__file__).parent / "library"
OPS = {"const": (1, 1), "neg": (1, 1), "add": (2, None), "sub": (2, 2), "mul": (2, None),
       "div": (2, 2), "min": (2, None), "max": (2, None)}


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

    def _inner_values(self, th: tuple, like: torch.Tensor | None):
        env = {p.name: v for p, v in zip(self.params, th)}
        for name, e in self.defs:
            env[name] = eval_expr(e, env)
        return env

    def eval(self, p, th, kids):
        env = self._inner_values(th, p)
        return _run(self.template, p, iter(self.exprs), env, kids)

    def bbox(self, v, kids):
        env = self._inner_values(v, None)
        return _template_bbox(self.template, iter(self.exprs), env, kids)


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
    nums = {}
    for k, e in dict(d.get("params", {})).items():
        if isinstance(e, (int, float)) and not isinstance(e, bool):
            nums[k] = e
        else:
            _check_expr(e, names, f"macro tree node {path}, parameter {k!r}")
            node_exprs.append((k, e))
    out["params"] = nums
    out["children"] = [_split_template(c, names, f"{path}/{i}", exprs) for i, c in enumerate(d.get("children", []))]
    return out


def _slots(node: Node) -> list[SlotNode]:
    if isinstance(node, SlotNode):
        return [node]
    return [s for c in node.children for s in _slots(c)]


def macro_type(spec: Mapping, source: str = "<memory>") -> type[Node]:
    """Build (not register) a node type from a macro definition; :class:`InputError` says what is wrong."""
    where = f"macro file {source}"
    for key in ("name", "params", "tree"):
        if key not in spec:
            raise InputError(f"{where}: missing the {key!r} field")
    name = str(spec["name"])
    try:
        params = tuple(Param(str(p["name"]), p["default"], p["lo"], p["hi"], p.get("kind", "float"),
                             p.get("doc", "")) for p in spec["params"])
    except (KeyError, TypeError, ValueError) as e:
        raise InputError(f"{where}: expected parameters with name, default, lo, hi, got a problem: {e}") from None
    names = {p.name for p in params}
    defs = []
    for dname, e in dict(spec.get("defs", {})).items():
        _check_expr(e, names, f"{where}, def {dname!r}")
        names.add(dname)
        defs.append((dname, e))
    raw_exprs: list = []
    tmpl_dict = _split_template(spec["tree"], names, "root", raw_exprs)
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
    dim = int(spec.get("dim", template.out_dim))
    if dim != template.out_dim:
        raise InputError(f"{where}: expected a {dim}D tree (the declared dim), got a {template.out_dim}D tree")
    attrs = {
        "type_name": name, "dim": dim, "arity": arity,
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

    Files may use macros from other files: loading repeats until no more files can be added. A file
    that repeats a registered macro to the letter (a copy of a shipped one) is accepted; a different
    definition under a registered name is an :class:`InputError` naming the file and the node.
    """
    paths = sorted(LIBRARY_DIR.glob("*.json"))
    for d in dirs or []:
        d = Path(d)
        if not d.is_dir():
            raise InputError(f"expected a macro library folder, got {d} (not found)")
        paths += sorted(d.glob("*.json"))
    specs = {path: _read_macro(path) for path in paths}
    pending, added, last_error = list(paths), [], {}
    while pending:
        progress = False
        for path in list(pending):
            if _known(specs[path], path):
                pending.remove(path)
                progress = True
                continue
            try:
                cls = macro_type(specs[path], str(path))
            except InputError as e:
                last_error[path] = str(e)
                continue
            NODES.add(cls.type_name, cls)
            added.append(cls.type_name)
            pending.remove(path)
            progress = True
        if not progress:
            raise InputError(last_error[pending[0]])
    return added


def _read_macro(path: Path) -> dict:
    spec = read_json(path, "macro file")
    if not isinstance(spec, dict):
        raise InputError(f"macro file {path}: expected a JSON object, got {type(spec).__name__}")
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


__all__ = ["macro_type", "load_library", "eval_expr", "MacroNode", "check_children"]
