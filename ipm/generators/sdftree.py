"""The universal generator: an SDF node tree (see :mod:`ipm.sdf`) used as a generator.

Its parameters are the tree's flat parameters (``<node label>.<param>``). Shipped trees are presets
(``ipm list presets``); any tree file (nested or flat JSON) works too.
"""

from __future__ import annotations

import json
from collections.abc import Mapping
from functools import lru_cache
from pathlib import Path

import torch

from ipm.errors import InputError
from ipm.files import read_json
from ipm.generators.base import PRESET_FAMILIES, Generator, PresetFamily, check_field_meshing, register_generator
from ipm.params import Value
from ipm.sdf.exact import ExactMesh, exact_mesh
from ipm.sdf.meshing import mesh_sdf
from ipm.sdf.tree import Tree, load_tree, tree_from_json
from ipm.types import TriMesh

PRESET_DIR = Path(__file__).resolve().parent.parent / "sdf" / "presets"


@lru_cache(maxsize=1)
def tree_presets() -> dict[str, Path]:
    """Shipped example trees by name."""
    return {p.stem: p for p in sorted(PRESET_DIR.glob("*.json"))}


class SdfTreeGenerator(Generator):
    """Generator over one SDF tree; discrete node values (counts, axes) are parameters too."""

    kind = "sdf"
    # what parameter files written from any tree say they are for (a named tree preset's name is its own)
    file_format = "sdftree"

    def __init__(self, tree: Tree, name: str = "sdftree", source: str | None = None,
                 start_variants: tuple[Mapping[str, Value], ...] = ()):
        self.tree = tree
        self.name = name
        self.source = source
        self.spec = tree.spec
        self.start_variants = tuple(start_variants)
        self.presets = {}
        self.description = f"SDF tree from {source}" if source else "SDF tree"
        self._cache: dict[tuple, Tree] = {}

    @staticmethod
    def from_file(path: str | Path) -> SdfTreeGenerator:
        """A generator over the SDF tree in a file (``InputError`` naming the file if it cannot be read), with the
        file's start variants (:func:`tree_start_variants`)."""
        tree = load_tree(path)
        variants = tree_start_variants(read_json(path, "tree file"), tree, f"tree file {path}")
        return SdfTreeGenerator(tree, "sdftree", str(path), variants)

    @staticmethod
    def from_preset(name: str) -> SdfTreeGenerator:
        """A generator over a shipped tree (:func:`tree_presets`), named after it; ``InputError`` lists the known
        names."""
        presets = tree_presets()
        if name not in presets:
            raise InputError(f"unknown tree preset {name!r}; known: {', '.join(sorted(presets))}")
        data = json.loads(presets[name].read_text())
        tree = tree_from_json(data)
        return SdfTreeGenerator(tree, name, f"preset {name}", tree_start_variants(data, tree, f"tree preset {name}"))

    def tree_for(self, discrete: Mapping[str, int]) -> Tree:
        """The tree with these discrete values (cached)."""
        key = tuple(sorted((k, int(v)) for k, v in discrete.items()))
        if not key:
            return self.tree
        if key not in self._cache:
            self._cache[key] = self.tree.with_values(dict(discrete))
        return self._cache[key]

    def sdf(self, theta: torch.Tensor, points: torch.Tensor, discrete: Mapping[str, int] | None = None):
        """Distances ``(...)`` at ``points: (..., 3)`` of the tree with these discrete values, negative inside."""
        return self.tree_for(discrete or {}).sdf(theta, points)

    def check_meshing(self, values: Mapping[str, Value], resolution: int) -> None:
        """Marching cubes over the field's bounds: the grid must fit in memory (:func:`check_field_meshing`)."""
        check_field_meshing(self.tree, values, resolution)

    def to_mesh(self, values: Mapping[str, Value], *, resolution: int | None = None, lod=None) -> TriMesh:
        """Marching cubes over the tree's bounds, ``resolution`` (default 128) samples along the longest side."""
        tree = self.tree.with_values(values)
        lo, hi = tree.bounds()
        return mesh_sdf(lambda p: tree.sdf(None, p), lo, hi, resolution or 128)

    def sdf_tree(self, values: Mapping[str, Value]) -> Tree:
        """The tree with ``values`` stored in it."""
        return self.tree.with_values(values)

    def exact_mesh(self, values: Mapping[str, Value], *, segments: int = 64, resolution: int = 128) -> ExactMesh:
        """The tree's exact CSG mesh at ``values`` (:func:`ipm.sdf.exact.exact_mesh`)."""
        return exact_mesh(self.tree.with_values(values), segments=segments, resolution=resolution)

    def metadata(self, values: Mapping[str, Value]) -> dict:
        """Adds the tree itself, with ``values`` filled in, as nested JSON (``"tree"``)."""
        from ipm.sdf.tree import tree_to_json

        return {"generator": self.name, "params": dict(values),
                "tree": tree_to_json(self.tree.with_values(values))["tree"]}


def tree_start_variants(data, tree: Tree, where: str) -> tuple[dict[str, Value], ...]:
    """A tree file's optional ``"start_variants"``: a list of objects of the tree's parameter values, each put on
    the defaults (or a fit's starting values) as another start of a fit (:attr:`Generator.start_variants`), for
    shapes of the tree's family the defaults are far from (the chair tree's stool: no back). ``InputError`` naming
    ``where`` for anything else, an unknown parameter or a value out of its bounds."""
    raw = data.get("start_variants", []) if isinstance(data, Mapping) else []
    if not isinstance(raw, list) or not all(isinstance(v, Mapping) and v for v in raw):
        raise InputError(f"{where}: start_variants: expected a list of non-empty objects of parameter values, "
                         f"got {json.dumps(raw)[:80]}")
    try:
        for variant in raw:
            tree.spec.validate(variant)
    except InputError as e:
        raise InputError(f"{where}: start_variants: {e}") from None
    return tuple(dict(v) for v in raw)


@register_generator("sdftree", from_file=SdfTreeGenerator.from_file)
def _default_tree() -> SdfTreeGenerator:
    """``sdftree`` alone is the classic CSG example; pass a tree file or preset for others."""
    return SdfTreeGenerator.from_preset("csg")


PRESET_FAMILIES.add("sdf trees", PresetFamily("sdftree", tree_presets, SdfTreeGenerator.from_preset))
