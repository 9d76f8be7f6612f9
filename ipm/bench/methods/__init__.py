"""Bench methods: one registry; a method turns input masks (and cameras) into a predicted mesh.

Each method is one module of this package that registers itself with ``@method(name, settings)``;
the registry :data:`METHODS` imports them all on first use (modules whose name starts with ``_`` are
shared helpers, not methods). A registered method is called as
``METHODS[name](task: Task, settings: dict, budget: int, seed: int) -> Prediction``.

Settings are parsed once, by the method's parser (a ``msgspec.Struct`` with constraints, or a
function), both by :func:`check_settings` (an experiment checked before any cell runs) and by the
method itself when it runs, so checking and running cannot disagree. Bad settings raise
:class:`~ipm.errors.InputError` naming the method, the setting and what is allowed.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from ipm.errors import InputError
from ipm.registry import Registry
from ipm.types import Camera, TriMesh


@dataclass
class Task:
    """What a method sees: K input masks ``(K, H, W)`` bool and their cameras."""

    masks: np.ndarray
    cameras: list[Camera]


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
