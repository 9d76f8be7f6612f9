"""Bench methods: one registry; a method turns input masks (and cameras) into a predicted mesh.

Each method is one module of this package that registers itself with ``@method(name, settings)``;
the registry :data:`METHODS` imports them all on first use (modules whose name starts with ``_`` are
shared helpers, not methods). A registered method is called as
``METHODS[name](task: Task, settings: dict, budget: int, seed: int) -> Prediction``.

Settings are parsed once, by the method's parser (a ``msgspec.Struct`` with constraints, or a
function), both by :func:`check_settings` (an experiment checked before any cell runs) and by the
method itself when it runs, so checking and running cannot disagree. Bad settings raise
:class:`~ipm.errors.InputError` naming the method, the setting and what is allowed.

Cues beyond silhouettes (issue #13): a method that can use depth maps or part labels of its input views
takes a ``cues`` setting (``["depth"]``, ``["parts:windows"]``: which cues the "user" supplies), parsed by
:func:`parse_cues` into a :class:`Cues` held as the ``cues`` attribute of its parsed settings. The harness
reads it (:meth:`Method.cues`), renders those cues of the input views from the target
(:func:`ipm.bench.protocol.render_views`) and fills the matching fields of the :class:`Task`; a method
without a ``cues`` setting gets masks and cameras only (and refuses the key as an unknown setting).
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from ipm.errors import InputError
from ipm.registry import Registry
from ipm.types import Camera, TriMesh


@dataclass
class Task:
    """What a method sees: K input masks ``(K, H, W)`` bool and their cameras, and the cues it asked for.

    depth: (K, H, W) float64 view-axis depth of the target in scene units, NaN off the object (only
    with the ``depth`` cue); parts: (K, H, W) int64, ``k`` where the pixel shows the target's part
    ``part_names[k]``, -1 where it shows none of them (background or another part; only with a
    ``parts`` cue)."""

    masks: np.ndarray
    cameras: list[Camera]
    depth: np.ndarray | None = None
    parts: np.ndarray | None = None
    part_names: tuple[str, ...] = ()


@dataclass(frozen=True)
class Cues:
    """Which cues of its input views a method is given besides the masks: ``depth`` and the names of the
    parts whose labels it sees (empty: none). The setting's text form is :meth:`names`."""

    depth: bool = False
    parts: tuple[str, ...] = ()

    def __bool__(self) -> bool:
        return self.depth or bool(self.parts)

    def names(self) -> list[str]:
        """``["depth", "parts:windows", ...]``: the setting that asks for these cues."""
        return (["depth"] if self.depth else []) + [f"parts:{p}" for p in self.parts]


NO_CUES = Cues()
CUE_FORMS = "depth, parts (every part) or parts:NAME"


@dataclass
class Prediction:
    mesh: TriMesh
    evaluations: int = 0
    wall_time_s: float = 0.0
    info: dict = field(default_factory=dict)


Parser = Callable[[str, dict], Any]


class Method:
    """A registered bench method: ``run(task, parsed settings, budget, seed)`` plus the parser of its
    settings dict. Calling it with a settings dict parses the dict, then runs."""

    def __init__(self, name: str, run: Callable[..., Prediction], parse: Parser):
        self.name, self.run, self.parse = name, run, parse
        self.__doc__ = run.__doc__
        self.__module__, self.__qualname__ = run.__module__, run.__qualname__  # for the registry's messages

    def __call__(self, task: Task, settings: dict, budget: int, seed: int) -> Prediction:
        return self.run(task, self.parse(self.name, settings), budget, seed)

    def cues(self, settings: dict) -> Cues:
        """The cues the method asks for with these settings: the ``cues`` attribute of its parsed
        settings (:func:`parse_cues`), none without one."""
        cues = getattr(self.parse(self.name, settings), "cues", NO_CUES)
        if not isinstance(cues, Cues):  # a member's bug, not the user's input
            raise TypeError(f"bench method {self.name}: its parsed settings' cues must be a Cues (parse_cues), "
                            f"got {type(cues).__name__}")
        return cues

    def __repr__(self) -> str:
        return f"<bench method {self.name!r}>"


METHODS: Registry[Callable[[Task, dict, int, int], Prediction]] = Registry("bench method", ["ipm.bench.methods"])


def method(name: str, settings: type | Parser) -> Callable[[Callable[..., Prediction]], Method]:
    """Decorator: register ``run(task, settings, budget, seed)`` as bench method ``name``; ``settings`` is
    a ``msgspec.Struct`` class (parsed by :func:`parse_struct`) or a parser ``(method, dict) -> value``."""
    parse = (lambda m, s: parse_struct(settings, m, s)) if isinstance(settings, type) else settings

    def deco(run: Callable[..., Prediction]) -> Method:
        return METHODS.add(name, Method(name, run, parse))

    return deco


def check_settings(method: str, settings: dict) -> None:
    """Raise :class:`InputError` unless ``method`` is a known bench method and ``settings`` are valid
    for it (known keys, right types, values in range), naming the method, the key and what is allowed.
    Members registered as plain functions (no parser) only have their name checked."""
    m = METHODS.get(method)
    if not isinstance(settings, dict):
        raise InputError(f"{method}: settings: expected a table of settings, got {type(settings).__name__}")
    if isinstance(m, Method):
        m.parse(method, settings)


def requested_cues(method: str, settings: dict) -> Cues:
    """The cues ``method`` asks for with ``settings`` (:meth:`Method.cues`; none for members registered as
    plain functions). Bad settings raise :class:`InputError` as in :func:`check_settings`."""
    m = METHODS.get(method)
    return m.cues(settings) if isinstance(m, Method) else NO_CUES


def parse_cues(method: str, value: object, parts: Sequence[str]) -> Cues:
    """The ``cues`` setting of ``method``: a list of ``"depth"``, ``"parts"`` (every name in ``parts``) and
    ``"parts:NAME"`` (NAME one of ``parts``, the parts the method can be told about), each at most once.
    :class:`InputError` names the setting and what is allowed."""
    def bad(why: str) -> InputError:
        names = f" (NAME one of {', '.join(parts)})" if parts else " (no parts here: depth only)"
        return InputError(f"{method}: setting cues: expected a list of {CUE_FORMS}{names}, got {value!r}{why}")

    if not isinstance(value, list) or not all(isinstance(v, str) for v in value):
        raise bad("")
    depth, named = False, []
    for v in value:
        kind, _, name = v.partition(":")
        if v == "depth":
            if depth:
                raise bad(": depth given twice")
            depth = True
        elif kind == "parts" and v in ("parts", *(f"parts:{p}" for p in parts)) and parts:
            new = list(parts) if v == "parts" else [name]
            twice = [p for p in new if p in named]
            if twice:
                raise bad(f": part {twice[0]} given twice")
            named += new
        else:
            raise bad(f": {v!r} is not one of these")
    return Cues(depth, tuple(named))


# -- msgspec settings --------------------------------------------------------------------------------

def parse_struct(cls: type, method: str, settings: dict):
    """``settings`` as an instance of the ``msgspec.Struct`` ``cls`` (declared with
    ``forbid_unknown_fields=True`` and ``msgspec.Meta`` bounds); :class:`InputError` otherwise."""
    import msgspec

    try:
        return msgspec.convert(settings, cls)
    except msgspec.ValidationError as e:
        raise InputError(_settings_message(cls, method, settings, str(e))) from None


def _settings_message(cls: type, method: str, settings: dict, error: str) -> str:
    from ipm.settings_check import allowed, error_path, field_types, unknown_field

    fields = field_types(cls)
    unknown = unknown_field(error)
    if unknown:
        return f"{method}: unknown setting {unknown!r}; expected one of: {', '.join(sorted(fields))}"
    path = error_path(error)
    if path and path[0] in fields:
        key = path[0]
        return f"{method}: setting {key}: expected {allowed(fields[key])}, got {settings.get(key)!r}"
    return f"{method}: settings: expected valid settings, got {error}"
