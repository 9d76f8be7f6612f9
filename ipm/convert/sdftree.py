"""Mesh -> SDF node tree (:mod:`ipm.sdf`), through the BSP fit (:mod:`ipm.convert.bsp`).

A BSP shape is a union of intersections of half-spaces, which the node algebra writes directly::

    intersection(union_n(convex_1, ..., convex_k), box)      convex_j = intersection(plane, intersection(plane, ...))

Each ``plane`` node is the half-space ``n . p - offset <= 0`` (``n`` from ``tilt`` and ``azimuth``:
``n = (sin t cos a, cos t, sin t sin a)``, see :func:`ipm.sdf._math.axis_from_tilt`). Only the planes that
carry a face of their convex are written (the domain-box planes too when a convex reaches the box); the
outer ``box`` (the polytope's bounding box, grown by 5%) changes nothing inside it and gives the tree
finite bounds for meshing. The result is an ordinary tree file: ``ipm generate out.json`` meshes it and
``ipm fit out.json`` refits its planes.
"""

from __future__ import annotations

import math
import time

import numpy as np

from ipm.convert import CONVERTERS
from ipm.convert.common import Conversion, Progress
from ipm.errors import InputError
from ipm.generators.bsp import convex_cells


def _plane_node(n: np.ndarray, d: float) -> dict:
    tilt = math.degrees(math.acos(float(np.clip(n[1], -1.0, 1.0))))
    azimuth = math.degrees(math.atan2(float(n[2]), float(n[0]))) if abs(math.sin(math.radians(tilt))) > 1e-12 else 0.0
    return {"node": "plane", "params": {"tilt": tilt, "azimuth": azimuth, "offset": float(d)}}


def _chain(op: str, nodes: list[dict]) -> dict:
    """Nested binary ``op`` nodes over ``nodes`` (one node stays itself)."""
    out = nodes[-1]
    for node in reversed(nodes[:-1]):
        out = {"node": op, "children": [node, out]}
    return out


def bsp_tree(planes: np.ndarray, selection: np.ndarray, extent: float, tol: float = 1e-7) -> dict | None:
    """The nested tree document ``{"tree": {...}}`` of a binary BSP: ``planes (p, 4)`` (a, d), ``selection
    (p, c)`` bool, domain box ``|x| <= extent``; None if every convex is empty."""
    convexes, lo, hi = [], np.full(3, np.inf), np.full(3, -np.inf)
    for _, _, N, off, v in convex_cells(planes, selection, extent):
        lo, hi = np.minimum(lo, v.min(0)), np.maximum(hi, v.max(0))
        faces = (np.abs(v @ N.T - off) <= tol * max(1.0, extent)).sum(0) >= 3
        convexes.append(_chain("intersection", [_plane_node(N[i], off[i]) for i in np.flatnonzero(faces)]))
    if not convexes:
        return None
    union = convexes[0] if len(convexes) == 1 else {"node": "union_n", "children": convexes}
    size = 2.0 * np.maximum(np.abs(lo), np.abs(hi)) * 1.05
    box = {"node": "box", "params": {"size_x": float(size[0]), "size_y": float(size[1]), "size_z": float(size[2])}}
    return {"tree": {"node": "intersection", "children": [union, box]}}


@CONVERTERS.register("sdftree")
def convert_sdftree(mesh, *, progress: Progress | None = None, seed: int = 0, **bsp_options) -> Conversion:
    """Fit a BSP to ``mesh`` (:func:`ipm.convert.bsp.fit_bsp`, same options) and write it as an SDF tree.

    Returns a :class:`~ipm.convert.common.Conversion` whose generator is an
    :class:`~ipm.generators.sdftree.SdfTreeGenerator`; ``stats`` holds the BSP's numbers plus ``nodes``
    and ``parameters`` of the tree.
    """
    from ipm.convert.bsp import fit_bsp
    from ipm.generators.sdftree import SdfTreeGenerator
    from ipm.sdf.tree import tree_from_json

    t0 = time.perf_counter()
    bsp = fit_bsp(mesh, progress=progress, seed=seed, **bsp_options)
    planes, T, _ = bsp.generator.planes_and_selection(bsp.values)
    doc = bsp_tree(planes, T >= 0.5, bsp.generator.extent)
    if doc is None:
        raise InputError("sdftree: the BSP fit is empty (no convex); nothing to write")
    tree = tree_from_json(doc)
    gen = SdfTreeGenerator(tree, "sdftree", "ipm convert --to sdftree")
    values = gen.spec.defaults()
    stats = {**{k: v for k, v in bsp.stats.items() if k != "seconds"},
             "nodes": _count(doc["tree"]), "parameters": gen.spec.n_continuous,
             "seconds": time.perf_counter() - t0}
    data = {"generator": "sdftree", **doc, "conversion": {"method": "sdftree (bsp)", "seed": seed, **stats},
            "frame": bsp.data.get("frame")}
    return Conversion(gen, values, data, stats)


def _count(node: dict) -> int:
    return 1 + sum(_count(c) for c in node.get("children", []))
