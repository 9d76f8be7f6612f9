"""Pre-order walks of node trees (without recursion, within the depth limit) and the flat parameter
vector."""

from __future__ import annotations

from collections.abc import Iterator, Sequence
from dataclasses import dataclass, replace

from ipm.errors import InputError
from ipm.params import ParamSpec
from ipm.tree.node import TreeNode

MAX_DEPTH = 64


def depth_error(depth: int) -> InputError:
    """The one-line error for input deeper than ``MAX_DEPTH``."""
    return InputError(f"expected a tree at most {MAX_DEPTH} levels deep (the limit), got {depth} or more")


@dataclass(frozen=True)
class Visit:
    """One node of a pre-order walk: the node, its parent's pre-order index (-1 at the root) and its
    path (``root/0/2``)."""

    node: TreeNode
    parent: int
    path: str


def preorder(root: TreeNode) -> list[Visit]:
    """The nodes of a tree in pre-order, without recursion; :class:`InputError` beyond ``MAX_DEPTH``."""
    out: list[Visit] = []
    stack = [(root, -1, "root", 1)]
    while stack:
        node, parent, path, depth = stack.pop()
        if depth > MAX_DEPTH:
            raise depth_error(depth)
        me = len(out)
        out.append(Visit(node, parent, path))
        for i in reversed(range(len(node.children))):
            stack.append((node.children[i], me, f"{path}/{i}", depth + 1))
    return out


def node_label(node: TreeNode, index: int) -> str:
    """A node's label: its name, else ``n<preorder index>_<type>``."""
    return node.name or f"n{index}_{node.type_name}"


def flat_spec(visits: Sequence[Visit]) -> tuple[ParamSpec, list[str], list[int]]:
    """``(spec, labels, offsets)``: the tree's parameters named ``<label>.<param>`` in pre-order, the
    labels, and each node's offset into ``theta`` (continuous parameters only)."""
    params, labels, offsets, off = [], [], [], 0
    for i, v in enumerate(visits):
        label = node_label(v.node, i)
        labels.append(label)
        offsets.append(off)
        for p, val in zip(v.node.param_defs(), v.node.values):
            params.append(replace(p, name=f"{label}.{p.name}", default=val))
            off += p.continuous
    if len(set(labels)) != len(labels):
        dup = sorted({x for x in labels if labels.count(x) > 1})
        raise InputError(f"tree: node names must be unique, got {', '.join(dup)} more than once")
    return ParamSpec(tuple(params)), labels, offsets


def rebuild(root: TreeNode, values: Iterator) -> TreeNode:
    """The tree with every node's values taken, in pre-order, from ``values``."""
    vals = tuple(next(values) for _ in root.param_defs())
    kids = tuple(rebuild(c, values) for c in root.children)
    return root.replace(values=vals, children=kids)


def same_tree(a: TreeNode, b: TreeNode) -> bool:
    """Structural equality: same types, sizes, names, values and children."""
    return type(a) is type(b) and a.to_dict() == b.to_dict()


__all__ = ["MAX_DEPTH", "Visit", "depth_error", "flat_spec", "node_label", "preorder", "rebuild", "same_tree"]
