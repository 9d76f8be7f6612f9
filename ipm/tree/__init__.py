"""One tree framework for SDF trees (:mod:`ipm.sdf`) and mesh trees (:mod:`ipm.generators.meshtree`).

A node *type* is a subclass of :class:`TreeNode` that declares its registry name, how many children it
takes and its named, bounded parameters; it registers itself in its family's
:class:`~ipm.registry.Registry` (one file per topic in the family's node package, found by package
discovery). A node *instance* is frozen data: its parameter values in declaration order, its children,
its size (sized nodes: the number of polygon or profile points) and an optional name (its label).

Trees flatten in pre-order into one :class:`~ipm.params.ParamSpec` whose names are
``<label>.<param>`` (label: the node's ``name`` or ``n<preorder index>_<type>``). Files are nested
JSON (``{"node": type, "name": ..., "size": ..., "params": {...}, "children": [...]}``) or the flat
form (pre-order ``structure`` tokens and one ``params`` list).

Trees are at most :data:`MAX_DEPTH` levels deep: deeper input is refused with an
:class:`~ipm.errors.InputError` before anything recurses (evaluation nests a few Python frames per level).
"""

from ipm.tree.files import check_depth, from_flat, node_from_dict, read_json, to_flat
from ipm.tree.node import TreeNode
from ipm.tree.walk import MAX_DEPTH, Visit, flat_spec, node_label, preorder, rebuild, same_tree

__all__ = ["MAX_DEPTH", "TreeNode", "Visit", "check_depth", "flat_spec", "from_flat", "node_from_dict",
           "node_label", "preorder", "read_json", "rebuild", "same_tree", "to_flat"]
