"""SDF node types, one topic per module (3D and 2D primitives, any-dimension operations, 3D-only
transforms, 2D-to-3D lifts). Every module here is imported by the registry
:data:`ipm.sdf.node.NODES` on first use: a new node type is one new module (or class) in this package.

The framework names are re-exported here for callers of the former ``ipm.sdf.nodes`` module.
"""

from ipm.sdf.node import NODES, Node, SlotNode, all_node_types, check_children, node_type, register
from ipm.sdf.tree import (
    Tree,
    from_flat,
    load_tree,
    node_from_dict,
    node_to_dict,
    to_flat,
    tree_from_json,
    tree_to_json,
)

__all__ = ["NODES", "Node", "SlotNode", "Tree", "all_node_types", "check_children", "from_flat", "load_tree",
           "node_from_dict", "node_to_dict", "node_type", "register", "to_flat", "tree_from_json",
           "tree_to_json"]
