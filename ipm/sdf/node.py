"""The SDF node base and its registry.

A node type is a small class: a registry name, its dimension (2 or 3, or 0 for "as its children"), how
many children it takes and of which dimension, its named parameters (with bounds and defaults) and one
vectorized ``eval(p, th, kids) -> distances``. ``th`` holds the node's parameter values in declaration
order (0-dim tensors for continuous ones, Python ints for discrete ones); ``kids`` are callables
``q -> distances`` evaluating the children at transformed points. Node types live one topic per module
in :mod:`ipm.sdf.nodes`; the registry :data:`NODES` imports that package on first use, then registers the
shipped macro nodes (:mod:`ipm.sdf.complex`).

Convention: signed distance is negative inside; 3D points are ``(..., 3)``, 2D points ``(..., 2)``.
"""

from __future__ import annotations

import importlib
from abc import abstractmethod
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from typing import ClassVar

import numpy as np
import torch

from ipm.errors import InputError
from ipm.params import Param
from ipm.registry import Registry
from ipm.tree import TreeNode

Eval = Callable[[torch.Tensor], torch.Tensor]
Box = tuple[np.ndarray, np.ndarray]

LEN = (1e-3, 20.0)
POS = (-20.0, 20.0)
ANGLE = (-360.0, 360.0)


def P(name: str, default: float, lo: float = LEN[0], hi: float = LEN[1], doc: str = "") -> Param:
    """A continuous parameter (bounds default to a positive length)."""
    return Param(name, default, lo, hi, "float", doc)


def _macro_nodes() -> None:
    """The shipped macro nodes are built from the other node types, so they are loaded after them (by name:
    :mod:`ipm.sdf.complex` imports this module)."""
    importlib.import_module("ipm.sdf.complex").load_library()


NODES: Registry = Registry("node type", packages=["ipm.sdf.nodes"], after=_macro_nodes)
register = NODES.register()


def node_type(name: str) -> type[Node]:
    """A node type by name; :class:`InputError` lists the known names."""
    return NODES.get(name)


def all_node_types() -> dict[str, type[Node]]:
    """Every registered node type by name (shipped macros included)."""
    return dict(NODES.items())


@dataclass(frozen=True, eq=False)
class Node(TreeNode):
    """An SDF node instance (see :class:`~ipm.tree.TreeNode`).

    Class attributes beyond the tree's: dim: 2 or 3, or 0 for "same as the children" (CSG);
    child_dim: dimension required of the children (default: ``dim``); exact: True (exact distance),
    False (a bound or an approximation).
    """

    _dim: int = field(default=0, repr=False)

    dim: ClassVar[int] = 3
    child_dim: ClassVar[int | None] = None
    exact: ClassVar[bool] = False

    @property
    def out_dim(self) -> int:
        """Dimension of this instance's output (CSG nodes take their children's)."""
        return self._dim or type(self).dim

    @classmethod
    def derived_fields(cls, kids):
        """``_dim``: the type's ``dim``, or for CSG nodes (``dim`` 0) the first child's (3 without children)."""
        return {"_dim": cls.dim or (kids[0].out_dim if kids else 3)}

    @classmethod
    def check_child_kinds(cls, kids, label):
        """``InputError`` unless every child has the required dimension (CSG: all children the same dimension)."""
        want = cls.child_dim or cls.dim
        if not kids:
            return
        if want:
            bad = [k for k in kids if k.out_dim != want]
            if bad:
                raise InputError(f"{label}: expected {want}D children, got a {bad[0].out_dim}D {bad[0].type_name}")
        elif len({k.out_dim for k in kids}) > 1:
            raise InputError(f"{label}: children must all be 2D or all 3D, got a mix")

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
        dim = self.out_dim
        for cand in ((f"{attr}2d", attr) if dim == 2 else (attr,)):
            cls = NODES.get(cand) if cand in NODES else None
            if cls is not None and cls.arity == 1 and (cls.child_dim or cls.dim or dim) == dim:
                def chain(*args, cls=cls, **kwargs):
                    return cls.make(*args, children=(self,), **kwargs)
                return chain
        raise AttributeError(f"{type(self).__name__} has no attribute or unary node {attr!r}")

    def __call__(self, points: torch.Tensor) -> torch.Tensor:
        """Evaluate at points ``(..., 3)`` with the stored values -> ``(...)``."""
        from ipm.sdf.tree import Tree

        return Tree(self).sdf(None, points)

    def __repr__(self) -> str:
        vals = ", ".join(f"{p.name}={v:g}" for p, v in zip(self.param_defs(), self.values))
        kids = ", ".join(repr(c) for c in self.children)
        inner = ", ".join(x for x in (vals, kids) if x)
        return f"{self.type_name}({inner})"


@dataclass(frozen=True, eq=False)
class SlotNode(Node):
    """A placeholder for the i-th child (``size``) of a macro node (only inside macro definitions)."""

    type_name: ClassVar[str] = "$slot"

    def eval(self, p, th, kids):
        """Always raises ``RuntimeError``: the tree compiler replaces slots by the macro's children."""
        raise RuntimeError("macro slots are evaluated by the tree compiler")

    def bbox(self, v, kids):
        """Always raises ``InputError``: a slot has no bounds of its own."""
        raise InputError("expected a node with bounds, got a macro slot")

    def to_dict(self) -> dict:
        """``{"slot": i}``: the slot's JSON form in a macro definition."""
        return {"slot": self.size}


def check_children(cls: type[Node], kids: tuple[Node, ...], size: int | None = None, path: str = "root") -> None:
    """Arity and dimension rules for ``cls`` with children ``kids``; errors name the node's path."""
    cls.check_children(kids, path)




class Primitive(Node):
    """A node without children (``dim`` 2 or 3)."""

    arity = 0


def primitive(dim: int, type_name: str, *params: Param, exact: bool = True,
              box: Callable[..., Box]) -> Callable:
    """Decorator: register a primitive node type from ``fn(p, *values) -> distances``.

    ``p: (..., dim)``, values are the parameters in declaration order (0-dim tensors), the result is
    ``(...)``; ``box(*values)`` (floats) gives its bounds. The function's docstring documents the node.
    """

    def deco(fn: Callable) -> type[Node]:
        cls = type(fn.__name__, (Primitive,), {
            "__doc__": fn.__doc__, "__module__": fn.__module__, "__qualname__": fn.__qualname__,
            "type_name": type_name, "dim": dim, "exact": exact, "params": tuple(params),
            "eval": lambda self, p, th, kids: fn(p, *th),
            "bbox": lambda self, v, kids: box(*v),
        })
        return register(cls)

    return deco



def operation(type_name: str, *params: Param, dims: Sequence[int] = (3,), child_dim: int | None = None,
              exact: bool = True, box: Callable[..., Box]) -> Callable:
    """Decorator: register a one-child node type from ``fn(child, p, *values) -> distances``, written once
    for every dimension in ``dims`` (fogleman/sdf's ``dn.py`` style).

    ``child`` evaluates the child at points ``(..., d)``; ``p: (..., dim)``; values are the parameters
    in declaration order; the result is ``(...)``. ``box(child_box, *values)`` gives its bounds. With
    ``dims=(3, 2)`` the 2D variant is registered as ``<type_name>2d``. ``params`` may instead be one
    callable ``dim -> tuple of Param`` (a translation has one offset per axis).
    """

    def deco(fn: Callable) -> type[Node]:
        cls = None
        for dim in dims:
            both = len(dims) > 1 and dim == 2
            decl = params[0](dim) if len(params) == 1 and callable(params[0]) else tuple(params)
            cls = register(type(fn.__name__ + ("2D" if both else ""), (Node,), {
                "__doc__": fn.__doc__, "__module__": fn.__module__,
                "__qualname__": fn.__qualname__ + ("2D" if both else ""),
                "type_name": type_name + ("2d" if both else ""), "dim": dim, "child_dim": child_dim,
                "arity": 1, "exact": exact, "params": decl,
                "eval": lambda self, p, th, kids: fn(kids[0], p, *th),
                "bbox": lambda self, v, kids: box(kids[0], *v),
            }))
        return cls

    return deco


__all__ = ["ANGLE", "LEN", "NODES", "POS", "Box", "Eval", "Node", "P", "Primitive", "SlotNode", "all_node_types",
           "check_children", "node_type", "operation", "primitive", "register"]
