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
import tomllib
from dataclasses import dataclass, field
from pathlib import Path


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


@dataclass(frozen=True)
class MethodSpec:
    name: str
    method: str
    views: tuple[int, ...] | None = None
    settings: dict = field(default_factory=dict)
    targets: tuple[str, ...] | None = None  # None: every target
    seeds: tuple[int, ...] | None = None    # None: the experiment's seeds (deterministic methods: one)
    seeds_by_views: dict | None = None      # views -> seeds, where the file gives seeds per number of views

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


def load_experiment(path: str | Path) -> Experiment:
    """Parse and check an experiment file; ``ValueError`` names the problem."""
    path = Path(path)
    if not path.is_file():
        raise ValueError(f"experiment file not found: {path}")
    try:
        data = tomllib.loads(path.read_text())
    except tomllib.TOMLDecodeError as e:
        raise ValueError(f"experiment file {path} is not valid TOML: {e}") from None
    from ipm.bench.methods import METHODS

    # paths in the file are relative to the project root: the experiments folder's parent
    root = path.resolve().parent.parent
    targets = []
    for i, t in enumerate(data.get("targets", [])):
        if "name" not in t or (("mesh" in t) == ("generator" in t)):
            raise ValueError(f"{path}: target {i} needs a name and exactly one of mesh or generator")
        if t.get("up", "y") not in ("y", "z"):
            raise ValueError(f"{path}: target {t['name']}: up must be y or z")
        if "class" in t and not (isinstance(t["class"], str) and t["class"]):
            raise ValueError(f"{path}: target {t['name']}: class must be a non-empty string, got {t['class']!r}")
        targets.append(TargetSpec(name=t["name"], mesh=t.get("mesh"), up=t.get("up", "y"),
                                  generator=t.get("generator"), preset=t.get("preset"),
                                  random=bool(t.get("random", False)), seed=int(t.get("seed", 0)),
                                  params=dict(t.get("params", {})), cls=t.get("class")))
    methods = []
    for i, m in enumerate(data.get("methods", [])):
        if "name" not in m or "method" not in m:
            raise ValueError(f"{path}: method {i} needs a name and a method")
        if m["method"] not in METHODS:
            raise ValueError(f"{path}: method {m['name']}: unknown method {m['method']!r}; "
                             f"known: {', '.join(sorted(METHODS))}")
        settings = {k: v for k, v in m.items() if k not in ("name", "method", "views", "targets", "seeds")}
        only = None
        if "targets" in m:
            only = tuple(str(n) for n in m["targets"])
            missing = sorted(set(only) - {t.name for t in targets})
            if missing:
                raise ValueError(f"{path}: method {m['name']}: unknown targets {', '.join(missing)}; "
                                 f"targets: {', '.join(t.name for t in targets)}")
        seeds, seeds_by_views = None, None
        if isinstance(m.get("seeds"), dict):
            seeds_by_views = {}
            for k, v in m["seeds"].items():
                if not (k.isdigit() and int(k) >= 1 and v and all(isinstance(x, int) for x in v)):
                    raise ValueError(f"{path}: method {m['name']}: seeds per views must map a number of views "
                                     f"to a non-empty list of integers, got {k} = {v!r}")
                seeds_by_views[int(k)] = tuple(int(x) for x in v)
        elif "seeds" in m:
            if not m["seeds"] or not all(isinstance(x, int) for x in m["seeds"]):
                raise ValueError(f"{path}: method {m['name']}: seeds must be a non-empty list of integers")
            seeds = tuple(int(x) for x in m["seeds"])
        if "by_class" in settings:
            by_class = settings["by_class"]
            applies = [t for t in targets if only is None or t.name in only]
            missing = sorted({t.name for t in applies if not isinstance(by_class, dict) or t.cls not in by_class})
            if missing or not all(isinstance(v, dict) for v in by_class.values()):
                raise ValueError(f"{path}: method {m['name']}: by_class must give a table of settings for the "
                                 f"class of every target it applies to; missing for {', '.join(missing)}")
        methods.append(MethodSpec(m["name"], m["method"], tuple(m["views"]) if "views" in m else None, settings,
                                  only, seeds, seeds_by_views))
    if not targets or not methods:
        raise ValueError(f"{path}: expected at least one [[targets]] and one [[methods]]")
    distance = data.get("distance", 3.2)
    if isinstance(distance, bool) or not isinstance(distance, (int, float)) or not distance > 0:
        raise ValueError(f"{path}: distance must be a positive number, got {distance!r}")
    names = [t.name for t in targets] + [m.name for m in methods]
    if len(set(names)) != len(names):
        raise ValueError(f"{path}: target and method names must be unique")
    return Experiment(name=str(data.get("name", path.stem)), root=root, targets=tuple(targets),
                      methods=tuple(methods), views=tuple(data.get("views", [1])),
                      seeds=tuple(data.get("seeds", [0])), budget=int(data.get("budget", 1000)),
                      size=int(data.get("size", 256)), heldout_size=int(data.get("heldout_size", 256)),
                      samples=int(data.get("samples", 10_000)), iou_resolution=int(data.get("iou_resolution", 64)),
                      distance=float(distance),
                      notes=str(data.get("notes", "")).strip())
