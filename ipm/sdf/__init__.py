"""The universal generator's node language.

Every registered node type is available as a factory: ``ipm.sdf.box(1, 2, 1)``,
``ipm.sdf.sphere(radius=0.6)``; chain transforms (``.translate(0, 1, 0)``) and combine with
``|`` (union), ``&`` (intersection) and ``-`` (subtraction). :class:`Tree` evaluates a node tree for
any parameter vector.
"""

from __future__ import annotations

from ipm.sdf.nodes import (
    Node,
    Tree,
    all_node_types,
    load_tree,
    node_from_dict,
    node_to_dict,
    node_type,
    tree_from_json,
    tree_to_json,
)


def __getattr__(name: str):
    types = all_node_types()
    if name in types:
        return types[name].make
    raise AttributeError(f"module 'ipm.sdf' has no attribute or node type {name!r}")


__all__ = ["Node", "Tree", "all_node_types", "load_tree", "node_from_dict", "node_to_dict", "node_type",
           "tree_from_json", "tree_to_json"]
