"""The mesh node tree: the mesh counterpart of the SDF node tree, on the same framework (:mod:`ipm.tree`).

Nodes are immutable data with named, bounded parameters, registered by type name in
:data:`MESH_NODES` (node types: :mod:`ipm.generators.meshtree.nodes`):

* primitives (no children), centered at the origin, Y up, sizes are full extents like the SDF
  nodes: ``box``, ``cylinder``, ``cone``, ``uv_sphere``, ``revolve``, ``extrude``;
* transforms (one child): ``translate``, ``rotate``, ``scale``, ``scale3``;
* ``merge`` (one or more children): their meshes side by side (concatenation, no CSG).

Parameters are flat and named ``<label>.<param>``; all are continuous. The shipped trees are JSON files
in ``presets/``. Modules: :mod:`.lod` (level of detail), :mod:`.node` (base classes and registry),
:mod:`.tree` (:class:`MeshTree`, Jacobian, files), :mod:`.generator` (the ``meshtree`` generator).
"""

from ipm.generators.meshtree.generator import (
    MeshTreeGenerator,
    load_preset,
    mesh_tree_presets,
    tree_preset_files,
)
from ipm.generators.meshtree.lod import LODS, MeshLod, resolve_lod
from ipm.generators.meshtree.node import MESH_NODES, MeshNode, Primitive, Transform, mesh_node_type
from ipm.generators.meshtree.nodes.transforms import rotation
from ipm.generators.meshtree.tree import (
    MeshTree,
    is_mesh_tree_file,
    load_mesh_tree,
    mesh_node_from_dict,
    mesh_node_to_dict,
    mesh_tree_from_json,
    mesh_tree_to_json,
)

__all__ = ["LODS", "MESH_NODES", "MeshLod", "MeshNode", "MeshTree", "MeshTreeGenerator", "Primitive", "Transform",
           "is_mesh_tree_file", "load_mesh_tree", "load_preset", "mesh_node_from_dict", "mesh_node_to_dict",
           "mesh_node_type", "mesh_tree_from_json", "mesh_tree_presets", "mesh_tree_to_json", "resolve_lod",
           "rotation", "tree_preset_files"]
