"""Messages for settings checked by msgspec: which field, what it allows, what it got.

Settings objects (the bench methods' ``msgspec.Struct`` classes, :class:`~ipm.optim.settings.FitSettings`
and its nested dataclasses) declare what each field allows in its type: ``Annotated[int, Meta(ge=1)]``,
``Literal[...]``. ``msgspec.convert`` checks a dict against them; the helpers here turn its
``ValidationError`` ("Expected `int` >= 1 - at `$.memetic.population`") into the project's one line
("memetic population: expected an integer >= 1, got 0"), reading what is allowed from the declared type.
A field may name what it holds with ``Meta(extra={"noun": "a seed"})``: "expected a seed >= 0".
"""

from __future__ import annotations

import math
import re

_UNKNOWN = re.compile(r"unknown field `([^`]*)`")
_AT = re.compile(r"- at `\$((?:\.[A-Za-z0-9_]+|\[[^\]]*\])*)`")


def unknown_field(error: str) -> str | None:
    """The unknown key a msgspec error complains about (``forbid_unknown_fields``), else None."""
    m = _UNKNOWN.search(error)
    return m.group(1) if m else None


def error_path(error: str) -> tuple[str, ...]:
    """The field names of the path a msgspec error points at, list indices dropped:
    "... - at `$.memetic.population`" -> ("memetic", "population"); "... - at `$.free[0]`" -> ("free",)."""
    m = _AT.search(error)
    if not m:
        return ()
    return tuple(re.findall(r"\.([A-Za-z0-9_]+)", re.sub(r"\[[^\]]*\]", "", m.group(1))))


def field_types(cls: type) -> dict:
    """``{field name: msgspec.inspect type}`` of a ``msgspec.Struct`` or dataclass ``cls``."""
    import msgspec.inspect as mi

    return {f.name: f.type for f in mi.type_info(cls).fields}


def allowed(t) -> str:
    """What a msgspec field type (``msgspec.inspect``) allows, in words: "an integer in [1, 5]",
    "a number >= 0", "one of 'a', 'b'"; a ``noun`` in the field's ``Meta(extra=...)`` replaces
    "an integer"/"a number" ("a seed >= 0")."""
    import msgspec.inspect as mi

    noun = None
    if isinstance(t, mi.Metadata):
        noun = (t.extra or {}).get("noun")
        t = t.type
    if isinstance(t, mi.UnionType):  # None (the default "unset") is not spelt out
        kinds = [k for k in t.types if not isinstance(k, mi.NoneType)]
        if noun is None:
            return " or ".join(allowed(k) for k in kinds) or "none"
        t = kinds[0] if len(kinds) == 1 else t
    if isinstance(t, (mi.IntType, mi.FloatType)):
        what = noun or ("an integer" if isinstance(t, mi.IntType) else "a number")
        lo = f"[{t.ge}" if t.ge is not None else f"({t.gt}" if t.gt is not None else None
        hi = f"{t.le}]" if t.le is not None else f"{t.lt})" if t.lt is not None else None
        if lo and hi:
            return f"{what} in {lo}, {hi}"
        bounds = [(">=", t.ge), (">", t.gt), ("<=", t.le), ("<", t.lt)]
        op, bound = next(((op, b) for op, b in bounds if b is not None), (None, None))
        if op:
            return f"{what} {op} {bound}"
        return what
    if noun is not None:
        return noun
    if isinstance(t, mi.LiteralType):
        return "one of " + ", ".join(repr(v) for v in t.values)
    if isinstance(t, mi.BoolType):
        return "true or false"
    if isinstance(t, mi.StrType):
        return "a string"
    if isinstance(t, (mi.ListType, mi.TupleType, mi.VarTupleType)):
        return "a list"
    if isinstance(t, mi.DictType):
        return "a dict"
    if isinstance(t, (mi.StructType, mi.DataclassType, mi.TypedDictType)):
        return "a table of settings"
    return type(t).__name__.removesuffix("Type").lower()


def first_infinite(data: dict, cls: type) -> tuple[str, ...] | None:
    """The path of the first float field of ``data`` (checked against the Struct or dataclass ``cls``,
    nested ones followed) that is NaN or infinite, which msgspec's bounds let through; else None."""
    import msgspec.inspect as mi

    for name, t in field_types(cls).items():
        v = data.get(name)
        inner = t.type if isinstance(t, mi.Metadata) else t
        if isinstance(inner, (mi.DataclassType, mi.StructType)) and isinstance(v, dict):
            sub = first_infinite(v, inner.cls)
            if sub:
                return (name, *sub)
        elif isinstance(v, float) and not math.isfinite(v):
            kinds = inner.types if isinstance(inner, mi.UnionType) else (inner,)
            if any(isinstance(k, (mi.FloatType, mi.Metadata)) and
                   isinstance(getattr(k, "type", k), mi.FloatType) for k in kinds):
                return (name,)
    return None
