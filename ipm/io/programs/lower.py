"""An SDF tree lowered to what a CAD program is written from: parts with their values as text, and the
variables that hold the values a user edits.

Every node of the tree becomes a :class:`Part`. Its parameters become variables named
``<label>_<parameter>`` (the label is the node's name, else ``n<pre-order index>_<type>``, as in the tree's
flat parameters), declared at the top of the program; a part refers to them by name. Macro nodes
(:mod:`ipm.sdf.complex`) are expanded: the macro's own parameters and ``defs`` become variables and the
parts of its body hold its expressions written over them, so that editing ``table_height`` moves the top
and lengthens the legs as the macro does. An axis (of ``mirror``, ``repeat``) decides which statement is
written, so it stays a number, not a variable.

Expressions (``add``, ``sub``, ``mul``, ``div``, ``neg``, ``min``, ``max``) are written in the syntax that
OpenSCAD and Python share: ``a + b``, ``-a``, ``min(a, b)``.
"""

from __future__ import annotations

import keyword
import re
from collections.abc import Mapping
from dataclasses import dataclass

import numpy as np

from ipm.sdf.complex import MacroNode, eval_expr
from ipm.sdf.node import Node, SlotNode
from ipm.sdf.tree import Tree
from ipm.tree import node_label, preorder

# parameters that pick the statement written (an axis): numbers in the program, not variables
STRUCTURAL = frozenset({"axis"})
_OPS = {"add": " + ", "sub": " - ", "mul": " * ", "div": " / "}


@dataclass(frozen=True)
class Val:
    """A value in a program: ``text`` (a variable, a number or an expression of variables) and its number."""

    text: str
    value: float

    def __str__(self) -> str:
        return self.text


@dataclass(frozen=True)
class Part:
    """One node of the program: its type, its label (statement names), its values by parameter name, its
    size (sized nodes: points, radii), its parts, its dimension and ``note``, what its comment says (the
    label, and the macro it stands for)."""

    kind: str
    label: str
    args: Mapping[str, Val]
    size: int | None
    children: tuple[Part, ...]
    dim: int
    note: str = ""

    def __getitem__(self, name: str) -> Val:
        return self.args[name]


@dataclass(frozen=True)
class Program:
    """A lowered tree: ``variables`` as ``(name, value, comment)`` in the order they are declared (a value
    may use the variables before it), the ``root`` part, and ``big``: the side of the cubes that stand for
    half-spaces (planes, mirrors, the kept side of a revolve), several times the tree's extent."""

    variables: tuple[tuple[str, Val, str], ...]
    root: Part
    big: float


def number(x: float) -> str:
    """A number as program text: ``0.5``, ``-2``, ``1e-06`` (12 significant digits, no trailing zeros)."""
    if float(x).is_integer() and abs(x) < 1e15:
        return str(int(x))
    return f"{float(x):.12g}"


def bare(text: str) -> str:
    """``text`` without the parentheses around the whole of it (``(a + b)`` -> ``a + b``)."""
    if not (text.startswith("(") and text.endswith(")")):
        return text
    depth = 0
    for i, c in enumerate(text):
        depth += {"(": 1, ")": -1}.get(c, 0)
        if depth == 0 and i < len(text) - 1:
            return text
    return text[1:-1]


def identifier(text: str) -> str:
    """``text`` made a variable name that OpenSCAD and Python both accept (letters, digits, ``_``)."""
    out = re.sub(r"\W", "_", text, flags=re.ASCII) or "part"
    if out[0].isdigit():
        out = "p_" + out
    return out + "_" if keyword.iskeyword(out) else out


def lower(tree: Tree) -> Program:
    """The program parts and variables of ``tree`` (its stored values); see the module docstring."""
    return _Lowering(tree).program()


class _Lowering:
    """The state of one lowering: the variables declared so far and the names taken."""

    def __init__(self, tree: Tree):
        self.tree = tree
        self.variables: list[tuple[str, Val, str]] = []
        self.taken: set[str] = set()
        self.labels = {id(v.node): node_label(v.node, i) for i, v in enumerate(preorder(tree.root))}

    def program(self) -> Program:
        """Lower the whole tree (variables first, in pre-order)."""
        root = self.part(self.tree.root)
        _, extent = _extent(self.tree.root)
        return Program(tuple(self.variables), root, big=float(number(round(4.0 * extent + 1.0, 1))))

    def name(self, text: str) -> str:
        """A fresh identifier from ``text`` (a suffix when taken)."""
        return fresh(text, self.taken)

    def declare(self, name: str, val: Val, comment: str = "") -> Val:
        """Declare a variable holding ``val``; the value that refers to it."""
        name = self.name(name)
        self.variables.append((name, val, comment))
        return Val(name, val.value)

    def part(self, node: Node) -> Part:
        """The part of a node of the user's tree: each parameter (axes aside) a variable."""
        label = self.labels[id(node)]
        args = {}
        for p, v in zip(node.param_defs(), node.values):
            val = Val(number(v), float(v))
            args[p.name] = val if p.name in STRUCTURAL else self.declare(f"{label}_{p.name}", val, p.doc)
        kids = tuple(self.part(c) for c in node.children)
        if isinstance(node, MacroNode):
            return self.macro(node, label, args, kids)
        return Part(node.type_name, label, args, node.size, kids, node.out_dim, label)

    def macro(self, node: MacroNode, label: str, args: dict, kids: tuple) -> Part:
        """A macro node's body, its expressions over the macro's variables (``args``) and its ``defs``."""
        env = dict(args)
        for dname, e in node.defs:
            env[dname] = self.declare(f"{label}_{dname}", expression(e, env), f"{node.type_name}: {dname}")
        counter = iter(range(10**9))
        body = self.template(node.template, iter(node.exprs), env, kids, label, counter)
        return Part(body.kind, label, body.args, body.size, body.children, body.dim,
                    f"{label}: the {node.type_name} macro")

    def template(self, node: Node, exprs_it, env: dict, slots: tuple, label: str, counter) -> Part:
        """A node of a macro body (pre-order, as :func:`ipm.sdf.complex._run` walks it); slots are the
        macro's children."""
        exprs = dict(next(exprs_it))
        if isinstance(node, SlotNode):
            return slots[node.size]
        defs = node.param_defs()
        args = {p.name: expression(exprs[i], env) if i in exprs else Val(number(v), float(v))
                for i, (p, v) in enumerate(zip(defs, node.values))}
        for i, p in enumerate(defs):
            if not p.continuous and i in exprs and p.name not in STRUCTURAL:
                args[p.name] = Val(f"round({args[p.name].text})", round(args[p.name].value))
        inner = f"{label}_{next(counter)}_{node.type_name}"
        kids = tuple(self.template(c, exprs_it, env, slots, label, counter) for c in node.children)
        if isinstance(node, MacroNode):
            mine = {p.name: self.declare(f"{inner}_{p.name}", args[p.name]) for p in defs}
            return self.macro(node, inner, mine, kids)
        return Part(node.type_name, inner, args, node.size, kids, node.out_dim)


def _extent(node: Node) -> tuple[tuple, float]:
    """``(box, extent)``: the node's bounds and the largest coordinate of any bounds in its subtree, each in
    its own frame (a place scales its child's frame)."""
    kids = [_extent(c) for c in node.children]
    lo, hi = node.bbox(tuple(float(v) for v in node.values), [k[0] for k in kids])
    return (lo, hi), max([float(np.max(np.abs(lo))), float(np.max(np.abs(hi)))] + [k[1] for k in kids])


def expression(e, env: Mapping[str, Val]) -> Val:
    """A macro expression (:func:`ipm.sdf.complex.eval_expr`) as program text over ``env``'s values, with its
    number; compound expressions are parenthesized."""
    value = float(eval_expr(e, {k: v.value for k, v in env.items()}))
    if isinstance(e, (int, float)):
        return Val(number(e), value)
    if isinstance(e, str):
        return env[e]
    (op, args), = e.items()
    parts = [expression(a, env).text for a in (args if isinstance(args, list) else [args])]
    if op == "const":
        return Val(parts[0], value)
    if op == "neg":
        return Val(f"(-{parts[0]})", value)
    if op in ("min", "max"):
        return Val(f"{op}({', '.join(parts)})", value)
    return Val("(" + _OPS[op].join(parts) + ")", value)


def fresh(text: str, taken: set[str]) -> str:
    """An identifier from ``text`` not in ``taken`` (``_2``, ``_3``, ... appended while it is), added to ``taken``."""
    base = identifier(text)
    out, k = base, 2
    while out in taken:
        out, k = f"{base}_{k}", k + 1
    taken.add(out)
    return out


def registrar(nodes: dict, uses_of: dict):
    """A language's decorator ``node(*kinds, uses=())``: records the decorated writer of these node types in
    ``nodes`` and the helpers it calls in ``uses_of`` (so that a program includes only the helpers it uses)."""

    def node(*kinds: str, uses: tuple[str, ...] = ()):
        def deco(fn):
            for k in kinds:
                nodes[k] = fn
                uses_of[k] = uses
            return fn
        return deco

    return node


def walk(part: Part):
    """Every part of the program, in pre-order."""
    stack = [part]
    while stack:
        p = stack.pop()
        yield p
        stack.extend(reversed(p.children))


def first_unmapped(program: Program, known) -> Part | None:
    """The first part (pre-order) whose type is not in ``known``, or None."""
    return next((p for p in walk(program.root) if p.kind not in known), None)


__all__ = ["STRUCTURAL", "Part", "Program", "Val", "bare", "expression", "first_unmapped", "identifier", "lower",
           "number", "walk"]
