"""The generator interface and registry.

A generator turns parameters into geometry. ``kind == "mesh"``: :meth:`Generator.mesh` returns a
:class:`~ipm.types.TriMesh` whose vertices are smooth functions of ``theta`` (the continuous
parameters) and whose faces depend only on the discrete values and the level of detail.
``kind == "sdf"``: :meth:`Generator.sdf` returns signed distances at points. Either way
:meth:`Generator.to_mesh` gives a mesh for export and pictures.
"""

from __future__ import annotations

from abc import ABC, abstractmethod
from collections.abc import Callable, Iterable, Mapping
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING, Any, Literal

import torch

from ipm.errors import InputError
from ipm.params import ParamSpec, Value
from ipm.registry import Registry
from ipm.types import TriMesh

if TYPE_CHECKING:
    from ipm.sdf.exact import ExactMesh

# Generators by name (a factory each), found in the modules of this package, then in plug-ins (the registry's
# ``after`` hook, which ipm.generators.plugins sets when discovery imports it)
GENERATORS: Registry[Callable[[], Generator]] = Registry("generator", packages=["ipm.generators"])
# Readers of generator files, by the file's ``"generator"`` field (SDF tree files may omit it: "sdftree")
FILE_FORMATS: Registry[Callable[[str], Generator]] = Registry("generator file format", packages=["ipm.generators"])
# Families of named shapes (tree presets): each gives ``names()`` and ``load(name) -> Generator``
PRESET_FAMILIES: Registry[PresetFamily] = Registry("preset family", packages=["ipm.generators"])


def register_generator(name: str, *, from_file: Callable[[str], Generator] | None = None):
    """Class or factory decorator: make ``name`` available to ``get_generator`` and the CLI.

    from_file: reads a JSON file whose ``"generator"`` field is ``name`` (a fitted or converted
    shape, a tree), so that ``get_generator(path)`` and ``ipm generate path`` load it."""

    def deco(factory):
        GENERATORS.add(name, factory)
        if from_file is not None:
            FILE_FORMATS.add(name, from_file)
        return factory

    return deco


@dataclass(frozen=True)
class PresetFamily:
    """Named shapes a module offers by name alone (``ipm generate table``): the shipped trees."""

    generator: str     # the generator that draws them
    names: Callable[[], Iterable[str]]
    load: Callable[[str], Generator]
    order: int = 0      # a name two families offer goes to the lower order (SDF trees before mesh trees)


class Generator(ABC):
    """Base of all generators. Subclasses set ``name``, ``kind``, ``spec`` and ``presets``."""

    name: str = ""
    kind: Literal["mesh", "sdf"] = "mesh"
    spec: ParamSpec
    presets: Mapping[str, Mapping[str, Value]] = {}
    description: str = ""
    # Adam step of silhouette fits in normalized parameter space (ipm.optim.fit.fit_lr); None: the fit's
    # default. Generators with many fine-grained parameters (a profile of radii) want a smaller one
    mask_lr: float | None = None
    # the parsimony rule of fits to one silhouette (ipm.optim.parsimony; FitSettings.part_ratio): the parts its
    # discrete values add (Param.adds) stay only where they bring the fit's loss below this share of the best loss
    # without them. None: 1, no rule (the lower loss wins)
    part_ratio: float | None = None
    # where fits start by default (FitSettings.init, ipm.optim.fit.init_mode): "presets", "learned" or "both" (the
    # two latter only where proposal weights exist for the generator; without them "both" is "presets")
    init: str = "presets"
    # names of the face groups (parts) its meshes can have, whatever the discrete values: what a part-label
    # target may name. Empty: the groups of the mesh at the default values
    parts: tuple[str, ...] = ()
    # variants of a fit's starting preset that its pose and discrete search also starts from (ipm.optim.pose.
    # preset_starts): each a set of overrides put on the starting preset, for shapes the presets leave out but
    # any preset may take (a vessel of the preset's profile with a square or a flat section)
    start_variants: tuple[Mapping[str, Value], ...] = ()

    # -- values --------------------------------------------------------------------------------
    def values(self, preset: str | None = None, overrides: Mapping[str, object] | None = None) -> dict:
        """Validated full parameter dict: defaults, then a preset, then overrides."""
        base = dict(self.spec.defaults())
        if preset is not None:
            if preset not in self.presets:
                raise InputError(f"unknown preset {preset!r} for {self.name}; "
                                 f"known: {', '.join(sorted(self.presets)) or '(none)'}")
            base.update(self.presets[preset])
        base.update(overrides or {})
        return self.spec.validate(base)

    def split(self, values: Mapping[str, Value], dtype=torch.float64, device=None):
        """``(theta (n,), discrete dict)`` from a validated dict."""
        return self.spec.to_vector(values, dtype, device), self.spec.discrete_values(values)

    # -- geometry ------------------------------------------------------------------------------
    def mesh(self, theta: torch.Tensor, discrete: Mapping[str, int], lod: Any = None) -> TriMesh:
        """Mesh generators: vertices differentiable in ``theta: (n,)``."""
        raise TypeError(f"{self.name} is an SDF generator; use sdf() or to_mesh()")

    def sdf(self, theta: torch.Tensor, points: torch.Tensor, discrete: Mapping[str, int]) -> torch.Tensor:
        """SDF generators: distances ``(...)`` at ``points: (..., 3)``, negative inside."""
        raise TypeError(f"{self.name} is a mesh generator; use mesh()")

    @abstractmethod
    def to_mesh(self, values: Mapping[str, Value], *, resolution: int | None = None,
                lod: Any = None) -> TriMesh:
        """A mesh for export and pictures (SDF generators mesh by marching cubes at ``resolution``)."""

    def exact_mesh(self, values: Mapping[str, Value], *, segments: int = 64, resolution: int = 128) -> ExactMesh:
        """An exact CSG mesh (:func:`ipm.sdf.exact.exact_mesh`): sharp edges kept, ``segments`` pieces per full
        circle, ``resolution`` for the marching cubes of the nodes that have no exact counterpart. Only SDF trees
        have one: other generators refuse (:class:`InputError`)."""
        raise InputError(f"{self.name}: exact meshes are made of SDF trees only (sdftree, the tree presets, tree "
                         "files); this generator makes its own mesh (use the default mesher)")

    def check_meshing(self, values: Mapping[str, Value], resolution: int) -> None:
        """Refuse (:class:`InputError`, with the largest resolution that fits) a meshing ``resolution`` whose grid
        would not fit in memory at ``values``; a generator that makes meshes itself (at a level of detail) has
        nothing to check. Generators meshed from a field override it (:func:`check_field_meshing`)."""
        return None

    def sdf_tree(self, values: Mapping[str, Value]):
        """The SDF tree (:class:`ipm.sdf.tree.Tree`) these values make, written as a CAD program by
        ``ipm generate -o x.scad``; generators that are not SDF trees refuse (:class:`InputError`)."""
        raise InputError(f"{self.name} is not an SDF tree: programs (.scad, .py) are written for SDF trees only "
                         "(tree presets, tree files, sdftree, and the run folders of their fits); "
                         "write a mesh (.obj, .glb, .usda, ...) instead")

    def metadata(self, values: Mapping[str, Value]) -> dict:
        """What travels with exported meshes (GLB extras and the ``.params.json`` sidecar)."""
        return {"generator": self.name, "params": dict(values)}


def check_field_meshing(tree, values: Mapping[str, Value], resolution: int) -> None:
    """:meth:`Generator.check_meshing` of a generator meshed from its field ``tree`` (marching cubes over the
    field's bounds at ``values``)."""
    from ipm.sdf.meshing import check_resolution

    check_resolution(resolution, *tree.with_values(values).bounds())


def get_generator(name: str, *, library: list[str] | None = None) -> Generator:
    """A generator by registry name, a generator file (``.json``; its ``"generator"`` field picks the
    reader, SDF trees may omit it), or a named shape of a preset family (the shipped trees).
    :class:`InputError` lists what is available."""
    if library:
        from ipm.sdf.complex import load_library

        load_library(library)
    if name in GENERATORS:
        return GENERATORS[name]()
    if name.endswith(".json") or Path(name).is_file():
        kind = _declared_generator(name) or "sdftree"
        if kind not in FILE_FORMATS:
            raise InputError(f"{name}: declares generator {kind!r}, which has no file format; files can "
                             f"hold: {', '.join(FILE_FORMATS.names())}")
        return FILE_FORMATS[kind](name)
    families = sorted((f for _, f in PRESET_FAMILIES.items()), key=lambda f: f.order)
    for family in families:
        if name in family.names():
            return family.load(name)
    shapes = sorted({n for f in families for n in f.names()})
    raise InputError(f"unknown generator {name!r}; registered: {', '.join(GENERATORS.names())}; "
                     f"named shapes: {', '.join(shapes)}; or pass a generator file (.json), or load the plug-in "
                     "that defines it (ipm --plugin FILE.py, or IPM_PLUGINS)")


def _declared_generator(path: str) -> str | None:
    """The ``"generator"`` field of a JSON file (None if absent: an SDF tree); an unreadable file is an
    :class:`InputError` naming it."""
    from ipm.tree import read_json  # a generator file may be a deep tree: the tree's depth limit applies

    data = read_json(path, "generator file")
    kind = data.get("generator") if isinstance(data, dict) else None
    return kind if isinstance(kind, str) else None


def check_format(data, fmt: str, what: str) -> None:
    """Refuse (:class:`InputError`) a generator file whose ``"generator"`` field is not ``fmt``."""
    if not isinstance(data, Mapping) or data.get("generator") != fmt:
        got = data.get("generator") if isinstance(data, Mapping) else data
        raise InputError(f"{what}: expected an object with \"generator\": \"{fmt}\", got {str(got)[:40]!r}")


def all_generators() -> dict[str, Callable[[], Generator]]:
    """Every registered generator factory by name."""
    return dict(GENERATORS.items())


class ValuesField(ABC):
    """A field generator with stored parameter values, offering the part of :class:`ipm.sdf.nodes.Tree`'s
    interface that fitting, rendering and the CLI use: ``sdf(theta, points)``, ``with_theta``,
    ``with_values``, ``theta``, ``values``. Subclasses give ``_eval(theta, points)`` and ``bounds()``."""

    def __init__(self, gen: Generator, values: Mapping[str, Value]):
        self.gen = gen
        self.spec = gen.spec
        self._values = gen.spec.validate(values)

    def theta(self, dtype=torch.float64, device=None) -> torch.Tensor:
        """The stored continuous values ``(n,)``."""
        return self.spec.to_vector(self._values, dtype, device)

    def values(self) -> dict:
        """A copy of the stored parameter values by name."""
        return dict(self._values)

    @abstractmethod
    def _eval(self, theta: torch.Tensor, points: torch.Tensor) -> torch.Tensor:
        """The field ``(...)`` at ``points (..., 3)`` for ``theta (n,)``."""

    @abstractmethod
    def bounds(self) -> tuple:
        """A conservative bounding box of the surface: ``(lo (3,), hi (3,))`` numpy arrays."""

    def sdf(self, theta: torch.Tensor | None, points: torch.Tensor) -> torch.Tensor:
        """Field ``(...)`` at ``points (..., 3)`` for ``theta (n,)`` (None: the stored values)."""
        if theta is None:
            theta = self.theta(points.dtype, points.device)
        return self._eval(theta, points)

    __call__ = sdf

    def with_values(self, values: Mapping[str, object]):
        """The same kind of field with some stored values replaced (validated by the generator's spec)."""
        return type(self)(self.gen, {**self._values, **values})

    def with_theta(self, theta: torch.Tensor):
        """The same kind of field with the continuous values from ``theta: (n,)``; ``InputError`` on a wrong length."""
        vals = theta.detach().cpu().double().tolist()
        if len(vals) != self.spec.n_continuous:
            raise InputError(f"expected theta of length {self.spec.n_continuous}, got {len(vals)}")
        return self.with_values(dict(zip((p.name for p in self.spec.continuous), vals)))
