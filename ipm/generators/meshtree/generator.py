"""The mesh tree generator and its shipped trees (``presets/*.json``: a tree plus optional named value
variants under ``"presets"``)."""

from __future__ import annotations

from collections.abc import Mapping
from functools import lru_cache
from pathlib import Path

import torch

from ipm import tree as T
from ipm.errors import InputError
from ipm.generators.base import PRESET_FAMILIES, Generator, PresetFamily, register_generator
from ipm.generators.meshtree.tree import MeshTree, load_mesh_tree, mesh_tree_from_json, mesh_tree_to_json
from ipm.params import Value
from ipm.types import TriMesh

PRESET_DIR = Path(__file__).resolve().parent / "presets"


@lru_cache(maxsize=1)
def tree_preset_files() -> dict[str, Path]:
    """Shipped mesh trees by name."""
    return {p.stem: p for p in sorted(PRESET_DIR.glob("*.json"))}


def mesh_tree_presets() -> tuple[str, ...]:
    """Names of the shipped mesh trees."""
    return tuple(tree_preset_files())


def load_preset(name: str) -> dict:
    """A shipped mesh tree file's data (``generator``, ``tree``, optional ``presets``)."""
    files = tree_preset_files()
    if name not in files:
        raise InputError(f"expected a mesh tree preset ({', '.join(files)}), got {name!r}")
    return T.read_json(files[name], "mesh tree preset")


class MeshTreeGenerator(Generator):
    """Generator over one mesh tree (all parameters continuous; ``discrete`` is ignored)."""

    kind = "mesh"

    def __init__(self, tree: MeshTree, name: str = "meshtree", source: str | None = None,
                 presets: Mapping[str, Mapping[str, Value]] | None = None):
        self.tree = tree
        self.name = name
        self.source = source
        self.spec = tree.spec
        self.presets = dict(presets or {})
        self.description = f"mesh tree from {source}" if source else "mesh tree"

    @staticmethod
    def from_file(path: str | Path) -> MeshTreeGenerator:
        """A generator over the mesh tree in a file (``InputError`` with a one-line reason if it cannot be read)."""
        return MeshTreeGenerator(load_mesh_tree(path), "meshtree", str(path))

    @staticmethod
    def from_preset(name: str) -> MeshTreeGenerator:
        """A generator over a shipped mesh tree, with the file's named presets; ``InputError`` lists the known names."""
        data = load_preset(name)
        return MeshTreeGenerator(mesh_tree_from_json(data), "meshtree", f"preset {name}", data.get("presets"))

    def mesh(self, theta: torch.Tensor, discrete: Mapping[str, int] | None = None, lod=None) -> TriMesh:
        """The tree's mesh for ``theta: (n,) float``; groups are the primitives' labels."""
        return self.tree.mesh(theta, lod)

    def jacobian(self, theta: torch.Tensor, discrete: Mapping[str, int] | None = None,
                 lod=None) -> torch.Tensor:
        """``(3V, n)`` Jacobian of the vertices from per-vertex 3x3 blocks (see :meth:`MeshTree.jacobian`)."""
        return self.tree.jacobian(theta, lod)

    def to_mesh(self, values: Mapping[str, Value], *, resolution: int | None = None, lod=None) -> TriMesh:
        """The mesh of a value dict at level of detail ``lod`` (``resolution`` is for SDF generators)."""
        return self.tree.mesh(self.spec.to_vector(self.spec.validate(values)), lod).detach()

    def metadata(self, values: Mapping[str, Value]) -> dict:
        """Adds the tree itself, with ``values`` filled in, as nested JSON (``"tree"``)."""
        return {"generator": self.name, "params": dict(values),
                "tree": mesh_tree_to_json(self.tree.with_values(values))["tree"]}


@register_generator("meshtree", from_file=MeshTreeGenerator.from_file)
def _meshtree() -> MeshTreeGenerator:
    """``meshtree`` alone is the table; other trees: :meth:`MeshTreeGenerator.from_preset` / ``from_file``."""
    return MeshTreeGenerator.from_preset("table")


PRESET_FAMILIES.add("mesh trees", PresetFamily("meshtree", mesh_tree_presets, MeshTreeGenerator.from_preset, order=1))
