"""The universal generator's node language.

Every registered node type is available as a factory: ``ipm.sdf.box(1, 2, 1)``,
``ipm.sdf.sphere(radius=0.6)``; chain transforms (``.translate(0, 1, 0)``) and combine with
``|`` (union), ``&`` (intersection) and ``-`` (subtraction). :class:`Tree` evaluates a node tree for
any parameter vector. Node types live in :mod:`ipm.sdf.nodes` (one topic per module) and register
themselves in :data:`NODES`; the framework they share with mesh trees is :mod:`ipm.tree`.
"""

from __future__ import annotations

from ipm.sdf.node import NODES, Node, all_node_types, node_type
from ipm.sdf.tree import Tree, load_tree, node_from_dict, node_to_dict, tree_from_json, tree_to_json


def __getattr__(name: str):
    if name in NODES:
        return NODES.get(name).make
    raise AttributeError(f"module 'ipm.sdf' has no attribute or node type {name!r}")


__all__ = ["NODES", "Node", "Tree", "all_node_types", "load_tree", "node_from_dict", "node_to_dict", "node_type",
           "tree_from_json", "tree_to_json"]
