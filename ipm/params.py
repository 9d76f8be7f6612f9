"""Named, bounded, typed parameters.

A generator exposes a flat, ordered :class:`ParamSpec`. Continuous (``float``) parameters form the
vector ``theta`` that Jacobians and gradient optimizers work on; discrete ones (``int`` counts and
``bool`` switches) fix the topology and travel as a plain ``dict[str, int]``. Everything converts
between a named dict, a vector, and a normalized ``[0, 1]`` vector (what nlopt and the genetic
search consume).
"""

from __future__ import annotations

import json
import math
from collections.abc import Iterable, Mapping
from dataclasses import dataclass, field, fields
from pathlib import Path
from typing import Literal

import numpy as np
import torch

from ipm.errors import InputError

Kind = Literal["float", "int", "bool"]
Value = float | int

# the largest random seed ipm takes (``--seed``, experiment files): every generator seeded with it takes it:
# numpy's legacy seed (below 2**32), torch and nlopt (64 bits) and OpenCV's (a C int: ipm mask's GrabCut)
MAX_SEED = 2**31 - 1


@dataclass(frozen=True)
class Param:
    """One parameter: a name, a type, closed bounds ``[lo, hi]`` and a default inside them."""

    name: str
    default: Value
    lo: Value
    hi: Value
    kind: Kind = "float"
    doc: str = ""
    # a fine-detail parameter (per-section offsets, ...): fits hold it at its starting value while they
    # search and free it in the final refinement (coarse to fine)
    detail: bool = False
    # a size repeated once per unit of this discrete count (a storey's height, per "floors"): a fit that
    # changes the count keeps size x count, so a candidate with more floors starts as tall as the building
    # it came from (ipm.optim.problem.Problem.carry)
    per: str | None = None
    # a discrete switch or count whose every unit adds a part of this name (a handle, a wing, a roof-top
    # box): a fit charges FitSettings.part_cost per unit, so a part stays only where it pays for itself
    adds: str | None = None
    # a shape parameter one view hardly determines (an oval section's depth along the line of sight reads
    # as the camera's elevation): single-view fits without depth charge FitSettings.anchor per unit of its normalized
    # distance from the starting value, so it leaves the start only where the view pays for it
    anchored: bool = False
    # where a shape is placed, not what it is (the outer frame of a tree written in a target's own frame:
    # ipm.fitting.framed): fits hold it at its value unless FitSettings.free names it
    held: bool = False

    def __post_init__(self) -> None:
        if self.kind not in ("float", "int", "bool"):
            raise InputError(f"parameter {self.name!r}: expected kind float|int|bool, got {self.kind!r}")
        if self.adds is not None and self.kind == "float":
            raise InputError(f"parameter {self.name!r}: adds {self.adds!r} expects a bool or int count, got a float")
        if self.kind == "bool" and (self.lo, self.hi) != (0, 1):
            object.__setattr__(self, "lo", 0)
            object.__setattr__(self, "hi", 1)
        if not (self.lo <= self.default <= self.hi):
            raise InputError(
                f"parameter {self.name!r}: default {self.default} is outside [{self.lo}, {self.hi}]"
            )

    @property
    def continuous(self) -> bool:
        """True for ``float`` parameters (part of ``theta``); ``int`` and ``bool`` ones are discrete."""
        return self.kind == "float"

    def check(self, value: object) -> Value:
        """Validate one value and return it in the parameter's type; raise ``ValueError`` otherwise.

        A ``bool`` parameter takes ``true``/``false`` or 0/1; the others take numbers only (``true`` is
        not 1.0). Non-finite values and numbers beyond the range of a double are refused."""
        if isinstance(value, (bool, np.bool_)):
            if self.kind != "bool":
                raise InputError(f"parameter {self.name!r} is {self.kind}: expected a number, got "
                                 f"{str(bool(value)).lower()}")
            value = int(value)
        if not isinstance(value, (int, float, np.integer, np.floating)):
            raise InputError(f"parameter {self.name!r}: expected a number, got {value!r}")
        try:
            as_float = float(value)
        except OverflowError:  # an integer beyond the range of a double
            raise InputError(f"parameter {self.name!r}: expected a value in [{self.lo}, {self.hi}], got an "
                             f"integer of {len(str(abs(int(value))))} digits") from None
        value = as_float if self.kind == "float" else value
        if not math.isfinite(as_float):
            raise InputError(f"parameter {self.name!r}: expected a finite number, got {as_float}")
        if self.kind != "float":
            if float(value) != round(float(value)):
                raise InputError(
                    f"parameter {self.name!r} is {self.kind}: expected a whole number in "
                    f"[{self.lo}, {self.hi}], got {value}"
                )
            value = int(round(float(value)))
        if not (self.lo <= value <= self.hi):
            raise InputError(
                f"parameter {self.name!r}: expected a value in [{self.lo}, {self.hi}], got {value}"
            )
        return value

    def to_json(self) -> dict:
        """The parameter as a JSON object; the optional flags (detail, per, adds, anchored, held) only when set."""
        out = {"name": self.name, "kind": self.kind, "default": self.default, "lo": self.lo,
               "hi": self.hi, "doc": self.doc}
        if self.detail:
            out["detail"] = True
        if self.per:
            out["per"] = self.per
        if self.adds:
            out["adds"] = self.adds
        if self.anchored:
            out["anchored"] = True
        if self.held:
            out["held"] = True
        return out


@dataclass(frozen=True)
class ParamSpec:
    """A flat, ordered list of parameters with unique names."""

    params: tuple[Param, ...]
    _index: dict[str, int] = field(init=False, repr=False, compare=False)

    def __post_init__(self) -> None:
        object.__setattr__(self, "params", tuple(self.params))
        index = {}
        for i, p in enumerate(self.params):
            if p.name in index:
                raise InputError(f"duplicate parameter name {p.name!r}")
            index[p.name] = i
        object.__setattr__(self, "_index", index)

    def __len__(self) -> int:
        return len(self.params)

    def __iter__(self):
        return iter(self.params)

    def __contains__(self, name: object) -> bool:
        return name in self._index

    def __getitem__(self, name: str) -> Param:
        try:
            return self.params[self._index[name]]
        except KeyError:
            raise InputError(self._unknown(name)) from None

    def _unknown(self, name: str) -> str:
        return f"unknown parameter {name!r}; valid names: {', '.join(self.names) or '(none)'}"

    @property
    def names(self) -> tuple[str, ...]:
        """Parameter names in order."""
        return tuple(p.name for p in self.params)

    @property
    def continuous(self) -> tuple[Param, ...]:
        """The ``float`` parameters in order: the coordinates of ``theta``."""
        return tuple(p for p in self.params if p.continuous)

    @property
    def discrete(self) -> tuple[Param, ...]:
        """The ``int`` and ``bool`` parameters in order."""
        return tuple(p for p in self.params if not p.continuous)

    @property
    def n_continuous(self) -> int:
        """Length ``n`` of ``theta``."""
        return len(self.continuous)

    def defaults(self) -> dict[str, Value]:
        """Every parameter's default by name."""
        return {p.name: p.default for p in self.params}

    def validate(self, values: Mapping[str, object], *, partial: bool = True) -> dict[str, Value]:
        """Check names, types and bounds; fill missing names with defaults (unless ``partial`` is False).

        Raises ``ValueError`` naming the first bad entry and what is allowed.
        """
        out = self.defaults()
        for name, value in values.items():
            if name not in self._index:
                raise InputError(self._unknown(name))
            out[name] = self[name].check(value)
        if not partial:
            missing = [n for n in self.names if n not in values]
            if missing:
                raise InputError(f"missing parameters: {', '.join(missing)}")
        return out

    # vectors -----------------------------------------------------------------------------------
    def lower(self, dtype=torch.float64, device=None) -> torch.Tensor:
        """Lower bounds of the continuous parameters, ``(n,)``."""
        return torch.tensor([float(p.lo) for p in self.continuous], dtype=dtype, device=device)

    def upper(self, dtype=torch.float64, device=None) -> torch.Tensor:
        """Upper bounds of the continuous parameters, ``(n,)``."""
        return torch.tensor([float(p.hi) for p in self.continuous], dtype=dtype, device=device)

    def to_vector(self, values: Mapping[str, Value], dtype=torch.float64, device=None) -> torch.Tensor:
        """Continuous values of a (validated) dict as ``theta: (n,)``."""
        full = self.validate(values)
        return torch.tensor([float(full[p.name]) for p in self.continuous], dtype=dtype, device=device)

    def discrete_values(self, values: Mapping[str, Value]) -> dict[str, int]:
        """The discrete part of a (validated) dict."""
        full = self.validate(values)
        return {p.name: int(full[p.name]) for p in self.discrete}

    def from_vector(self, theta: torch.Tensor | Iterable[float],
                    discrete: Mapping[str, int] | None = None) -> dict[str, Value]:
        """Named dict from ``theta: (n,)`` and the discrete values (defaults where absent)."""
        vals = [float(v) for v in (theta.detach().cpu().tolist() if torch.is_tensor(theta) else theta)]
        if len(vals) != self.n_continuous:
            raise InputError(f"expected a vector of {self.n_continuous} continuous values, got {len(vals)}")
        out = self.defaults()
        for name, value in (discrete or {}).items():
            p = self[name]
            if p.continuous:
                raise InputError(f"parameter {name!r} is continuous; pass it in the vector")
            out[name] = p.check(value)
        out.update({p.name: v for p, v in zip(self.continuous, vals)})
        return out

    def normalize(self, theta: torch.Tensor) -> torch.Tensor:
        """Map ``theta: (..., n)`` to ``[0, 1]`` per coordinate (zero-width ranges map to 0)."""
        lo, hi = self.lower(theta.dtype, theta.device), self.upper(theta.dtype, theta.device)
        span = torch.where(hi > lo, hi - lo, torch.ones_like(hi))
        return (theta - lo) / span

    def denormalize(self, u: torch.Tensor) -> torch.Tensor:
        """Inverse of :meth:`normalize`."""
        lo, hi = self.lower(u.dtype, u.device), self.upper(u.dtype, u.device)
        return lo + u * (hi - lo)

    def random(self, rng: np.random.Generator) -> dict[str, Value]:
        """Uniform sample within the bounds (integers uniform over their range)."""
        out: dict[str, Value] = {}
        for p in self.params:
            if p.continuous:
                out[p.name] = float(rng.uniform(p.lo, p.hi))
            else:
                out[p.name] = int(rng.integers(int(p.lo), int(p.hi) + 1))
        return out

    def to_json(self) -> list[dict]:
        """The parameters as a list of JSON objects (:meth:`Param.to_json`), in order."""
        return [p.to_json() for p in self.params]


def parse_assignment(text: str) -> tuple[str, float]:
    """Parse ``NAME=VALUE`` (from ``--set``); raise ``ValueError`` with the expected form."""
    name, sep, raw = text.partition("=")
    if not sep or not name.strip():
        raise InputError(f"expected NAME=VALUE, got {text!r}")
    try:
        value = float(raw)
    except ValueError:
        raise InputError(f"expected a number after '=' in {text!r}") from None
    if math.isinf(value) and "inf" not in raw.lower():  # 1e400: beyond a double, read as infinity
        raise InputError(f"parameter {name.strip()!r}: expected a number of magnitude at most 1.8e308 (a double), "
                         f"got {raw.strip()}")
    return name.strip(), value


def load_param_file(path: str | Path) -> tuple[str | None, dict[str, object]]:
    """Read ``{"generator": ..., "params": {...}}``; return (generator name or None, raw params)."""
    from ipm.files import read_json

    data = read_json(path, "parameter file")
    if not isinstance(data, dict) or not isinstance(data.get("params"), dict):
        raise InputError(f"parameter file {path}: expected an object with a 'params' object")
    gen = data.get("generator")
    return (str(gen) if gen is not None else None), dict(data["params"])


def param_file_json(generator: str, values: Mapping[str, Value]) -> str:
    """The text of a parameter file."""
    return json.dumps({"generator": generator, "params": dict(values)}, indent=2) + "\n"


def check_fields(cls: type, keys: Iterable[str], what: str, noun: str = "field(s)") -> None:
    """``ValueError`` naming the keys that are not fields of the dataclass ``cls``, and the ones that are."""
    known = {f.name for f in fields(cls)}
    unknown = sorted(set(keys) - known)
    if unknown:
        raise InputError(f"{what}: unknown {noun} {', '.join(unknown)}; expected some of {', '.join(sorted(known))}")


def dataclass_from(cls: type, values: Mapping[str, object], what: str, noun: str = "field(s)"):
    """``cls(**values)`` for a dataclass ``cls``, after :func:`check_fields`."""
    check_fields(cls, values, what, noun)
    return cls(**dict(values))
