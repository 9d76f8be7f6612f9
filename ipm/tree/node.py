"""The node base shared by SDF nodes and mesh nodes: frozen data with declared, bounded parameters."""

from __future__ import annotations

import operator
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from typing import ClassVar

from ipm.errors import InputError
from ipm.params import Param, ParamSpec


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
        """This instance's parameter declarations (its type's, at its size)."""
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
        values = ParamSpec(defs).validate(given)
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


__all__ = ["TreeNode"]
