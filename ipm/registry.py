"""One registry for every kind of extension: nodes, generators, losses, search strategies, bench methods.

A registry maps names to members and knows the packages its members live in. The first lookup imports
every module of those packages (members register themselves with the :meth:`Registry.register`
decorator when their module is imported), so adding a member is one new file in that package and no
edit anywhere else::

    STRATEGIES = Registry("search strategy", packages=["ipm.optim.strategies"])

    @STRATEGIES.register("coordinate")
    def coordinate(problem, ...): ...

Lookups of unknown names raise :class:`~ipm.errors.InputError` listing the known ones.
"""

from __future__ import annotations

import importlib
import pkgutil
from collections.abc import Callable, Iterator, Sequence
from contextlib import contextmanager
from contextvars import ContextVar
from typing import Generic, TypeVar

from ipm.errors import InputError

T = TypeVar("T")

# the plug-in being imported (a file or an entry point): a name it takes twice is the plug-in's fault, bad input
# naming it, not a bug of ipm's
_PLUGIN: ContextVar[str | None] = ContextVar("ipm_plugin", default=None)


@contextmanager
def loading_plugin(source: str):
    """Within this block, registering a name that is taken is an :class:`InputError` naming ``source``."""
    token = _PLUGIN.set(source)
    try:
        yield
    finally:
        _PLUGIN.reset(token)


class Registry(Generic[T]):
    """Named members of one kind, discovered from ``packages`` on first use.

    kind: what a member is, for messages ("node type", "generator").
    packages: dotted package names whose modules are imported (all of them, recursively, except
        modules whose name starts with ``_``) before the first lookup.
    after: run once after the packages are imported, on the first lookup: members from outside the package
        (plug-ins: :mod:`ipm.generators.plugins`).
    """

    def __init__(self, kind: str, packages: Sequence[str] = (), after: Callable[[], None] | None = None):
        self.kind = kind
        self.packages = list(packages)
        self.after = after
        self._members: dict[str, T] = {}
        self._discovered: set[str] = set()
        self._after_done = False

    # -- registering ---------------------------------------------------------------------------
    def add(self, name: str, member: T) -> T:
        """Register ``member`` as ``name``; a different member under a taken name is a bug (loud)."""
        if not isinstance(name, str) or not name:
            raise TypeError(f"{self.kind}: names are non-empty strings, got {name!r}")
        old = self._members.get(name)
        if old is not None and old is not member and not _same_definition(old, member):
            if _PLUGIN.get() is not None:
                raise InputError(f"{_PLUGIN.get()}: {self.kind} {name!r} is taken by {_where(old)}; give yours "
                                 "another name")
            raise RuntimeError(f"{self.kind} {name!r} is registered twice ({_where(old)} and {_where(member)})")
        self._members[name] = member
        return member

    def register(self, name: str | None = None) -> Callable[[T], T]:
        """Decorator: register a class or function under ``name`` (default: its ``type_name`` or
        ``name`` attribute, else its ``__name__``)."""

        def deco(member: T) -> T:
            key = name or getattr(member, "type_name", None) or getattr(member, "name", None) or member.__name__
            return self.add(key, member)

        return deco

    def remove(self, name: str) -> None:
        """Forget a member (tests that register a throwaway one clean up with this)."""
        self._members.pop(name, None)

    # -- looking up ----------------------------------------------------------------------------
    def discover(self) -> None:
        """Import every module of the registry's packages (once per package), then run ``after`` (once)."""
        for pkg_name in self.packages:
            if pkg_name in self._discovered:
                continue
            self._discovered.add(pkg_name)
            pkg = importlib.import_module(pkg_name)
            for info in pkgutil.walk_packages(getattr(pkg, "__path__", []), prefix=pkg_name + "."):
                if not info.name.rsplit(".", 1)[-1].startswith("_"):
                    importlib.import_module(info.name)
        if self.after is not None and not self._after_done:
            self._after_done = True
            self.after()

    @property
    def discovered(self) -> bool:
        """Whether the first lookup has happened (the packages imported and ``after`` run)."""
        return self._after_done or (self.after is None and set(self.packages) <= self._discovered)

    def current(self) -> dict[str, T]:
        """The members registered so far, without discovering (for code that runs during discovery)."""
        return dict(self._members)

    def get(self, name: str) -> T:
        """The member called ``name``; :class:`InputError` lists the known names."""
        self.discover()
        try:
            return self._members[name]
        except (KeyError, TypeError):
            raise InputError(f"unknown {self.kind} {name!r}; known: {', '.join(self.names())}") from None

    def names(self) -> list[str]:
        """Sorted member names."""
        self.discover()
        return sorted(self._members)

    def items(self) -> list[tuple[str, T]]:
        """``(name, member)`` pairs sorted by name, after importing the registry's packages."""
        self.discover()
        return sorted(self._members.items())

    def __getitem__(self, name: str) -> T:
        return self.get(name)

    def __contains__(self, name: object) -> bool:
        self.discover()
        return name in self._members

    def __iter__(self) -> Iterator[str]:
        return iter(self.names())

    def __len__(self) -> int:
        self.discover()
        return len(self._members)

    def __repr__(self) -> str:
        return f"Registry({self.kind!r}, {len(self._members)} members, packages={self.packages})"


def _where(member: object) -> str:
    return f"{getattr(member, '__module__', '?')}.{getattr(member, '__qualname__', type(member).__name__)}"


def _same_definition(a: object, b: object) -> bool:
    """A module imported twice (``python -m`` of a member's module) re-defines the same member."""
    return _where(a) == _where(b)
