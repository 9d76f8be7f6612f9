"""Edits of a structure search, one module each, registered by name in :data:`EDITS`.

An edit is a function ``(tree, context) -> list[Proposal]``: from a candidate tree (nested JSON dict, not
changed) and a :class:`Context` (the target's samples, the regions the candidate misses and covers too much,
the primitive kinds allowed) it proposes new trees, each with a short label for the trajectory. The search
refines and scores every proposal; an edit only says where to start. Adding an edit is one new module in
this package with ``@EDITS.register("name")``; ``StructureSettings.edits`` then accepts its name.
"""

from __future__ import annotations

from dataclasses import dataclass

from ipm.optim.structure.candidate import Region
from ipm.optim.structure.samples import Samples
from ipm.registry import Registry

EDITS = Registry("structure edit", packages=["ipm.optim.structure.edits"])


@dataclass(frozen=True)
class Context:
    """What an edit may look at: ``missing`` regions (target inside, tree outside) and ``extra`` regions
    (the reverse), largest first; ``kinds``: the primitive kinds to propose."""

    samples: Samples
    missing: tuple[Region, ...]
    extra: tuple[Region, ...]
    kinds: tuple[str, ...]


@dataclass(frozen=True)
class Proposal:
    label: str
    tree: dict


__all__ = ["EDITS", "Context", "Proposal"]
