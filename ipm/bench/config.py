"""Experiment files (``experiments/*.toml``): targets, views, methods, seeds, budget.

    name = "small"
    views = [1, 2]
    seeds = [0, 1]
    budget = 300
    size = 128                        # input mask size (DESIGN.md: 256)
    heldout_size = 128

    distance = 3.2                    # camera distance of every view (DESIGN.md: 3.2)

    [[targets]]
    name = "cup_1"
    mesh = "../shared/data/real/vessels/ocrtoc_mug.ply"   # relative to the experiment file's project root
    up = "z"
    class = "mug"                     # tables also give the mean per class

    [[targets]]
    name = "mug_sample"
    generator = "dishes"
    preset = "mug"                    # or: random = true, seed = 3

    [[methods]]
    name = "ipm-dishes"
    method = "ipm"
    generator = "dishes"
    discrete = "memetic"

    [[methods]]
    name = "ipm-dishes+depth"
    method = "ipm"
    generator = "dishes"
    cues = ["depth"]                  # also given the input views' depth maps ("parts:handle": handle labels)

    [[methods]]
    name = "visual-hull"
    method = "visual-hull"
    views = [2, 6, 12]                # a method may override the views it is given
    seeds = [0]                       # ... and the seeds (a deterministic method needs one)
    targets = ["cup_1"]               # ... and the targets it applies to

    [[methods]]
    name = "ipm"
    method = "ipm"
    views = [1, 2, 4]
    seeds = { 1 = [0, 1, 2], 2 = [0], 4 = [0] }   # seeds per number of views
    [methods.by_class]                # settings per target class, over the method's own
    mug = { generator = "dishes", preset = "mug" }
"""

from __future__ import annotations

import itertools
import re
import tomllib
from dataclasses import dataclass, field
from pathlib import Path
from typing import Annotated, Any, Literal

import msgspec
from msgspec import Meta

from ipm.errors import InputError
from ipm.params import MAX_SEED

MAX_SIZE = 2048   # pixels a side of input and held-out masks
MAX_VIEWS = 64
# how deeply an experiment's tables and arrays may nest (its own nest 4 deep): deeper text is refused
# before tomllib, which recurses into every inline table and array, parses it
MAX_NESTING = 32
# TOML's strings (basic and literal, one line or several) and comments, where brackets do not nest
_TOML_SKIPPED = re.compile(r'"""(?:\\.|[^\\])*?"""|\'\'\'.*?\'\'\'|"(?:\\.|[^"\\\n])*"|\'[^\'\n]*\'|#[^\n]*',
                           re.S)


# a dotted key (a.b.c) or a number with a decimal point, once strings are blanked
_DOTTED = re.compile(r'[\w"-]+(?:[ \t]*\.[ \t]*[\w"-]+)+')


def toml_nesting(text: str) -> int:
    """An upper bound of how deeply tables and arrays nest in TOML ``text``, without parsing it: the
    deepest nesting of arrays and inline tables (strings and comments skipped; a table header ``[[a]]``
    counts 2 on its line) plus the most dots in a dotted key (``a.b.c = 1`` nests 3 deep; a number's
    decimal point counts one too, which the limit leaves room for). tomllib takes time quadratic in a
    dotted key's length, and recurses into arrays and inline tables."""
    text = _TOML_SKIPPED.sub('""', text)
    depth = deepest = 0
    for c in text:
        if c in "[{":
            depth += 1
            deepest = max(deepest, depth)
        elif c in "]}":
            depth -= 1
    return deepest + max((m.group().count(".") for m in _DOTTED.finditer(text)), default=0)


def _data_depth(data: object) -> int:
    """How deeply the tables and arrays of parsed TOML nest (dotted keys ``a.b.c = 1`` nest without
    brackets), without recursion."""
    deepest, stack = 0, [(data, 1)]
    while stack:
        d, depth = stack.pop()
        kids = d.values() if isinstance(d, dict) else d if isinstance(d, list) else None
        if kids is not None:
            deepest = max(deepest, depth)
            stack.extend((k, depth + 1) for k in kids)
    return deepest


@dataclass(frozen=True)
class TargetSpec:
    name: str
    mesh: str | None = None
    up: str = "y"
    generator: str | None = None
    preset: str | None = None
    random: bool = False
    seed: int = 0
    params: dict = field(default_factory=dict)
    cls: str | None = None  # the "class" key: tables give means per class
    split: str | None = None  # which part of the set (e.g. "tune", "validation"): `ipm bench --split` runs one


@dataclass(frozen=True)
class MethodSpec:
    name: str
    method: str
    views: tuple[int, ...] | None = None
    settings: dict = field(default_factory=dict)
    targets: tuple[str, ...] | None = None  # None: every target
    seeds: tuple[int, ...] | None = None    # None: the experiment's seeds (deterministic methods: one)
    seeds_by_views: dict | None = None      # views -> seeds, where the file gives seeds per number of views
    budget: int | None = None               # None: the experiment's budget

    def budget_or(self, default: int) -> int:
        return default if self.budget is None else self.budget

    def seeds_for(self, views: int) -> tuple[int, ...] | None:
        if self.seeds_by_views is not None:
            return self.seeds_by_views.get(views, (0,))
        return self.seeds

    def settings_for(self, target: TargetSpec) -> dict:
        """The method's settings for ``target``: its own, then those of ``by_class`` for the target's class."""
        out = {k: v for k, v in self.settings.items() if k != "by_class"}
        by_class = self.settings.get("by_class")
        if by_class is not None:
            out.update(by_class[target.cls])
        return out


@dataclass(frozen=True)
class Cell:
    """One run of the grid: a method on a target from K views with a seed."""

    target: str
    method: str
    views: int
    seed: int

    @property
    def key(self) -> str:
        return f"{self.target}|{self.method}|{self.views}|{self.seed}"


@dataclass(frozen=True)
class Experiment:
    name: str
    root: Path
    targets: tuple[TargetSpec, ...]
    methods: tuple[MethodSpec, ...]
    views: tuple[int, ...] = (1,)
    seeds: tuple[int, ...] = (0,)
    budget: int = 1000
    size: int = 256
    heldout_size: int = 256
    samples: int = 10_000
    iou_resolution: int = 64
    distance: float = 3.2   # camera distance of the input and held-out views (DESIGN.md)
    notes: str = ""  # free text for the results README (protocol deviations, comparisons)

    def cells(self) -> list[Cell]:
        out = []
        for t, m in itertools.product(self.targets, self.methods):
            if m.targets is not None and t.name not in m.targets:
                continue
            for k in m.views or self.views:
                for s in m.seeds_for(int(k)) or self.seeds:
                    out.append(Cell(t.name, m.name, int(k), int(s)))
        return out

    def target(self, name: str) -> TargetSpec:
        return next(t for t in self.targets if t.name == name)

    def method(self, name: str) -> MethodSpec:
        return next(m for m in self.methods if m.name == name)


# The file's schema (msgspec validates types, ranges and unknown keys; messages give the key's path)
Seed = Annotated[int, Meta(ge=0, le=MAX_SEED)]
Views = Annotated[list[Annotated[int, Meta(ge=1, le=MAX_VIEWS)]], Meta(min_length=1)]


class _TargetFile(msgspec.Struct, forbid_unknown_fields=True, rename={"cls": "class"}):
    name: Annotated[str, Meta(min_length=1)]
    mesh: str | None = None
    up: Literal["y", "z"] = "y"
    generator: str | None = None
    preset: str | None = None
    random: bool = False
    seed: Seed = 0
    params: dict[str, Any] = {}
    cls: Annotated[str, Meta(min_length=1)] | None = None
    split: Annotated[str, Meta(min_length=1)] | None = None


class _MethodKeys(msgspec.Struct, forbid_unknown_fields=True):
    """The keys of a ``[[methods]]`` table that are not the method's own settings."""

    name: Annotated[str, Meta(min_length=1)]
    method: str
    views: Views | None = None
    targets: list[str] | None = None
    seeds: Annotated[list[Seed], Meta(min_length=1)] | dict[str, Annotated[list[Seed], Meta(min_length=1)]] | None \
        = None
    by_class: dict[str, dict[str, Any]] | None = None
    # the method's own budget instead of the experiment's (a bound such as the coverage table's 8-view fit,
    # not a competitor: tables compare methods at one budget)
    budget: Annotated[int, Meta(ge=1, le=10_000_000)] | None = None


class _File(msgspec.Struct, forbid_unknown_fields=True):
    targets: Annotated[list[_TargetFile], Meta(min_length=1)]
    methods: Annotated[list[dict[str, Any]], Meta(min_length=1)]
    name: Annotated[str, Meta(min_length=1)] | None = None
    views: Views = msgspec.field(default_factory=lambda: [1])
    seeds: Annotated[list[Seed], Meta(min_length=1)] = msgspec.field(default_factory=lambda: [0])
    budget: Annotated[int, Meta(ge=1, le=10_000_000)] = 1000
    size: Annotated[int, Meta(ge=16, le=MAX_SIZE)] = 256
    heldout_size: Annotated[int, Meta(ge=16, le=MAX_SIZE)] = 256
    samples: Annotated[int, Meta(ge=100, le=10_000_000)] = 10_000
    iou_resolution: Annotated[int, Meta(ge=8, le=512)] = 64
    distance: Annotated[float, Meta(gt=0)] = 3.2
    notes: str = ""


def _convert(data, schema, where: str):
    from ipm.settings_check import first_infinite

    try:
        out = msgspec.convert(data, schema)
    except msgspec.ValidationError as e:
        raise InputError(f"{where}: {e}") from None
    bad = first_infinite(data, schema)  # msgspec's bounds let NaN and infinities through
    if bad:
        raise InputError(f"{where}: {'.'.join(bad)}: expected a finite number, got {data[bad[0]]!r}")
    return out


def _check_cues(cues, target: TargetSpec) -> None:
    """:class:`InputError` unless ``target`` can show the ``cues`` (:class:`ipm.bench.methods.Cues`):
    depth maps come from any target mesh, part labels only from a generator sample's parts."""
    if not cues.parts:
        return
    if target.generator is None:
        raise InputError(f"target {target.name}: setting cues: expected parts of a generator target, got "
                         f"{', '.join(cues.names())} for the mesh file {target.mesh} (it has no part labels; "
                         "give this method generator targets, or depth only)")
    from ipm.generators import get_generator

    gen = get_generator(target.generator)
    known = tuple(gen.parts) or gen.to_mesh(gen.values(target.preset, target.params)).group_names
    unknown = [p for p in cues.parts if p not in known]
    if unknown:
        raise InputError(f"target {target.name}: setting cues: expected parts of {gen.name} "
                         f"({', '.join(known) or 'none'}), got {', '.join(unknown)}")


def _read_data(path: Path) -> dict:
    """The experiment file's TOML tables, nested at most :data:`MAX_NESTING` deep."""
    if not path.is_file():
        raise InputError(f"experiment file not found: {path}")
    from ipm.files import read_text

    try:
        text = read_text(path, "experiment file")
    except InputError as e:
        raise InputError(str(e).replace("UTF-8 text", "UTF-8 TOML text")) from None
    depth = toml_nesting(text)
    if depth <= MAX_NESTING:
        try:
            data = tomllib.loads(text)
        except tomllib.TOMLDecodeError as e:
            raise InputError(f"experiment file {path} is not valid TOML: {e}") from None
        depth = _data_depth(data)
    if depth > MAX_NESTING:
        raise InputError(f"experiment file {path}: expected tables and arrays nested at most {MAX_NESTING} deep "
                         f"(the limit), got {depth} deep")
    return data


def _target_spec(path: Path, t: _TargetFile) -> TargetSpec:
    """The target ``t`` of the file, checked to be a mesh or a generator (with its preset, random and params)."""
    if (t.mesh is None) == (t.generator is None):
        raise InputError(f"{path}: target {t.name}: expected exactly one of mesh or generator")
    if t.generator is None and (t.preset is not None or t.random or t.params):
        raise InputError(f"{path}: target {t.name}: preset, random and params go with a generator target")
    return TargetSpec(name=t.name, mesh=t.mesh, up=t.up, generator=t.generator, preset=t.preset,
                      random=t.random, seed=t.seed, params=dict(t.params), cls=t.cls, split=t.split)


def _method_spec(path: Path, i: int, m: dict, targets: list[TargetSpec]) -> MethodSpec:
    """The ``i``-th method ``m`` of the file, its settings checked for every target it applies to."""
    from ipm.bench.methods import check_settings, requested_cues

    keys = {k: v for k, v in m.items() if k in _MethodKeys.__struct_fields__}
    mk = _convert(keys, _MethodKeys, f"{path}: method {m.get('name', i)}")
    settings = {k: v for k, v in m.items() if k not in _MethodKeys.__struct_fields__}
    only = None
    if mk.targets is not None:
        only = tuple(mk.targets)
        missing = sorted(set(only) - {t.name for t in targets})
        if missing:
            raise InputError(f"{path}: method {mk.name}: unknown targets {', '.join(missing)}; "
                             f"targets: {', '.join(t.name for t in targets)}")
    seeds, seeds_by_views = None, None
    if isinstance(mk.seeds, dict):
        bad = [k for k in mk.seeds if not (k.isdigit() and int(k) >= 1)]
        if bad:
            raise InputError(f"{path}: method {mk.name}: seeds per views must map a number of views (1 or "
                             f"more) to a list of seeds, got {bad[0]!r}")
        seeds_by_views = {int(k): tuple(v) for k, v in mk.seeds.items()}
    elif mk.seeds is not None:
        seeds = tuple(mk.seeds)
    applies = [t for t in targets if only is None or t.name in only]
    if mk.by_class is not None:
        settings["by_class"] = mk.by_class
        missing = sorted({t.name for t in applies if t.cls not in mk.by_class})
        if missing:
            raise InputError(f"{path}: method {mk.name}: by_class must give a table of settings for the "
                             f"class of every target it applies to; missing for {', '.join(missing)}")
    spec = MethodSpec(mk.name, mk.method, tuple(mk.views) if mk.views else None, settings, only, seeds,
                      seeds_by_views, mk.budget)
    for t in applies or targets[:1]:
        try:
            check_settings(mk.method, spec.settings_for(t))
            if applies:
                _check_cues(requested_cues(mk.method, spec.settings_for(t)), t)
        except InputError as e:
            raise InputError(f"{path}: method {mk.name}" + (f", target {t.name}" if mk.by_class else "")
                             + f": {e}") from None
    return spec


def _of_split(path: Path, targets: list[TargetSpec], split: str | None) -> list[TargetSpec]:
    """The targets of ``split`` (all of them when it is None); :class:`InputError` when it names none."""
    if split is None:
        return targets
    kept = [t for t in targets if t.split == split]
    if not kept:
        splits = sorted({t.split for t in targets if t.split is not None})
        have = ", ".join(splits) or "it has none: give targets a split key"
        raise InputError(f"--split {split}: expected a split of {path} ({have}), got one with no target")
    return kept


def load_experiment(path: str | Path, split: str | None = None) -> Experiment:
    """Parse and check an experiment file; :class:`~ipm.errors.InputError` names the file and the problem.
    With ``split``, only the targets of that split (their ``split`` key) are kept.

    Everything a run needs is checked here, without running: the nesting (at most :data:`MAX_NESTING`
    deep, checked on the text before it is parsed), keys (unknown ones are refused), types and ranges
    (seeds from 0 to :data:`ipm.params.MAX_SEED`), names, every method's settings for every target it applies to
    (:func:`ipm.bench.methods.check_settings`: unknown generators, presets and settings keys), and that
    the cues a method asks for can be drawn from those targets (:func:`_check_cues`)."""
    path = Path(path)
    f = _convert(_read_data(path), _File, str(path))
    # paths in the file are relative to the project root: the experiments folder's parent
    root = path.resolve().parent.parent
    targets = [_target_spec(path, t) for t in f.targets]
    methods = [_method_spec(path, i, m, targets) for i, m in enumerate(f.methods)]
    names = [t.name for t in targets] + [m.name for m in methods]
    if len(set(names)) != len(names):
        dup = sorted({n for n in names if names.count(n) > 1})
        raise InputError(f"{path}: target and method names must be unique; repeated: {', '.join(dup)}")
    return Experiment(name=f.name or path.stem, root=root, targets=tuple(_of_split(path, targets, split)),
                      methods=tuple(methods), views=tuple(f.views), seeds=tuple(f.seeds), budget=f.budget, size=f.size,
                      heldout_size=f.heldout_size, samples=f.samples, iou_resolution=f.iou_resolution,
                      distance=float(f.distance), notes=f.notes.strip())
