"""Everything a structure search can be told: :class:`StructureSettings`, checked in one place."""

from __future__ import annotations

from dataclasses import asdict, dataclass, fields
from typing import Annotated

from msgspec import Meta

from ipm.errors import InputError
from ipm.optim.structure.program import PRIMITIVES
from ipm.optim.structure.samples import FINE_RAYS, RAYS
from ipm.settings_check import allowed, error_path, field_types, first_infinite

DEFAULT_EDITS = ("add", "replace", "delete", "merge", "mirror", "turn", "smooth")


@dataclass(frozen=True)
class StructureSettings:
    """Defaults are what ``ipm fit --structure search`` uses (unit-sphere frame: targets normalized as
    DESIGN.md's protocol does)."""

    budget: Annotated[int, Meta(ge=1)] = 16000                # evaluations (Adam steps + scores) in all
    seed: Annotated[int, Meta(ge=0)] = 0                      # the target's samples
    beam: Annotated[int, Meta(ge=1, le=64)] = 3               # trees kept from one round to the next
    proposals: Annotated[int, Meta(ge=1, le=1024)] = 12       # edits tried per beam member and round
    steps: Annotated[int, Meta(ge=1, le=100_000)] = 40        # Adam steps refining each proposal
    polish: Annotated[int, Meta(ge=0, le=1_000_000)] = 600    # Adam steps of the best tree at the end
    lr: Annotated[float, Meta(gt=0.0, le=1.0)] = 0.01         # Adam step (raw parameter units)
    node_cost: Annotated[float, Meta(ge=0.0, le=1.0)] = 0.005  # score per node: the IoU a node must buy
    max_nodes: Annotated[int, Meta(ge=2, le=1024)] = 24       # no proposal grows beyond this
    rounds: Annotated[int, Meta(ge=0, le=10_000)] = 16        # rounds of edits at most
    patience: Annotated[int, Meta(ge=1, le=1000)] = 2         # rounds without a better best before stopping
    regions: Annotated[int, Meta(ge=1, le=64)] = 2            # missing / extra regions an add edit tries
    min_region: Annotated[float, Meta(ge=0.0, le=1.0)] = 0.003  # smallest region, share of the target's cells
    kinds: tuple[str, ...] = PRIMITIVES                       # primitive kinds proposed
    edits: tuple[str, ...] = DEFAULT_EDITS                    # edits proposed (ipm.optim.structure.edits)
    surface: Annotated[int, Meta(ge=1, le=10_000_000)] = 2000  # target surface points (mesh targets)
    volume: Annotated[int, Meta(ge=16, le=10_000_000)] = 6000  # target volume points
    grid: Annotated[int, Meta(ge=8, le=256)] = 48             # scoring grid, cells along the longest side
    rays: Annotated[int, Meta(ge=4, le=512)] = RAYS           # silhouette rays a side of each view (masks)
    fine_rays: Annotated[int, Meta(ge=0, le=2048)] = FINE_RAYS  # ... near the outlines (a multiple; 0: none)

    def check(self) -> None:
        """Raise :class:`~ipm.errors.InputError` with one line for a field of the wrong type or range, an
        unknown primitive kind or edit, fine rays that do not divide into rays."""
        import msgspec

        from ipm.optim.structure.edits import EDITS

        data = {f.name: getattr(self, f.name) for f in fields(self)}
        data["kinds"], data["edits"] = list(self.kinds), list(self.edits)
        try:
            msgspec.convert(data, StructureSettings)
        except msgspec.ValidationError as e:
            raise InputError(_message(data, error_path(str(e)), str(e))) from None
        bad = first_infinite(data, StructureSettings)
        if bad:
            raise InputError(_message(data, bad, ""))
        if not self.kinds or any(k not in PRIMITIVES for k in self.kinds):
            raise InputError(f"structure kinds: expected some of {', '.join(PRIMITIVES)}, got {list(self.kinds)}")
        known = EDITS.names()
        if not self.edits or any(e not in known for e in self.edits):
            raise InputError(f"structure edits: expected some of {', '.join(known)}, got {list(self.edits)}")
        if self.fine_rays % self.rays:
            raise InputError(f"structure fine rays: expected 0 or a multiple of rays ({self.rays}), got "
                             f"{self.fine_rays}")
        if self.polish >= self.budget:
            raise InputError(f"structure polish: expected fewer steps than the budget ({self.budget}), got "
                             f"{self.polish}")

    def to_json(self) -> dict:
        """The settings as a JSON object (``kinds`` and ``edits`` as lists)."""
        d = asdict(self)
        d["kinds"], d["edits"] = list(self.kinds), list(self.edits)
        return d

    @classmethod
    def from_json(cls, data: dict) -> StructureSettings:
        """Settings from :meth:`to_json`'s object, checked; ``InputError`` for an unknown key or a bad value."""
        if not isinstance(data, dict):
            raise InputError(f"structure settings: expected an object, got {type(data).__name__}")
        known = {f.name for f in fields(cls)}
        unknown = sorted(set(data) - known)
        if unknown:
            raise InputError(f"structure settings: unknown key {unknown[0]!r}; known: {', '.join(sorted(known))}")
        d = dict(data)
        for k in ("kinds", "edits"):
            if k in d:
                if not isinstance(d[k], (list, tuple)):
                    raise InputError(f"structure {k}: expected a list of names, got {d[k]!r}")
                d[k] = tuple(d[k])
        s = cls(**d)
        s.check()
        return s


def _message(data: dict, path: tuple[str, ...], error: str) -> str:
    types = field_types(StructureSettings)
    if not path or path[0] not in types:
        return f"structure settings: {error}"
    return f"structure {path[0].replace('_', ' ')}: expected {allowed(types[path[0]])}, got {data.get(path[0])!r}"


__all__ = ["DEFAULT_EDITS", "StructureSettings"]
