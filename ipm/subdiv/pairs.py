"""Training pairs for neural subdivision with exact correspondences, from the dishes generator.

A dish's body is a loft: rings of ``radial`` vertices at profile samples that are evenly spaced within
each of its segments (bottom rings, outer wall, rim arc, inner wall, inner bottom), closed by a pole at
each end. At ``2^l`` times the resolution (:func:`fine_lod`) the finer body holds every coarse vertex
*exactly* (same parameters, same point of the generator's surface), and every vertex that ``l`` levels of
Loop topology insert sits at a vertex of the finer body: the one halfway between its edge's ends in the
loft's (ring, angle) grid. So the ground truth of every level is read off the generator itself, with no
projection (Liu et al. 2020 had to build such maps with edge collapses and conformal flattening).

Every part a discrete switch adds (:func:`body_only`: the handle, the spout tube, the knob) is left out: their end caps
are fans around poles that are not on their sweeps' grids, so the inserted vertices of the caps have no exact
counterpart.
"""

from __future__ import annotations

from dataclasses import dataclass, replace

import numpy as np
import torch

from ipm.errors import InputError

# the coarse level of detail of the training pairs: 12 x 15 rings + 2 poles = 182 vertices
COARSE = {"radial": 12, "wall": 9, "rim": 1, "bottom": 1, "handle_sections": 3, "handle_ring": 3}
# the share of each continuous parameter's range by which a preset is perturbed
SPREAD = 0.05
# how far a coarse vertex may lie from its finer twin (float64 rounding only)
EXACT = 1e-9


@dataclass(frozen=True)
class Pair:
    """A coarse mesh and the exact positions of the vertices each subdivision level makes.

    verts (V, 3), faces (F, 3); levels[l] is ``(V_{l+1}, 3)``: the positions after l + 1 levels, in the
    vertex order of :func:`ipm.subdiv.halfflap.next_level` (old vertices first, then one per edge)."""

    verts: torch.Tensor
    faces: np.ndarray
    levels: tuple[torch.Tensor, ...]


def fine_lod(lod, factor: int):
    """The dish level of detail whose body grid is ``factor`` times finer in both directions."""
    return replace(lod, radial=factor * lod.radial, wall=factor * (lod.wall - 1) + 1,
                   rim=factor * (lod.rim + 1) - 1, bottom=factor * lod.bottom)


def _grid(n_loops: int, k: int) -> np.ndarray:
    """``(V, 2)`` integer (ring, angle) coordinates of a pole-capped loft's vertices; poles: angle -1."""
    rings = np.stack(np.meshgrid(np.arange(1, n_loops + 1), np.arange(k), indexing="ij"), -1).reshape(-1, 2)
    return np.concatenate([[[0, -1]], rings, [[n_loops + 1, -1]]]).astype(np.int64)


def _index(coords: np.ndarray, n_loops: int, k: int) -> np.ndarray:
    """Vertex indices of (ring, angle) coordinates in a pole-capped loft with ``n_loops`` rings of ``k``."""
    r, j = coords[:, 0], coords[:, 1]
    idx = 1 + (r - 1) * k + j
    idx = np.where(r == 0, 0, idx)
    return np.where(r == n_loops + 1, n_loops * k + 1, idx)


def _midpoints(coords: np.ndarray, edges: np.ndarray, k: int) -> np.ndarray:
    """The (ring, angle) coordinates, in units of the next level, of the vertices inserted on ``edges``
    ``(E, 2)`` of a level whose rings have ``k`` vertices (angles wrap around)."""
    a, b = coords[edges[:, 0]], coords[edges[:, 1]]
    r = a[:, 0] + b[:, 0]
    ja, jb = a[:, 1], b[:, 1]
    # across the seam (angle k - 1 next to 0, or k - 2 next to 0 beside a pole's fan): unwrap the smaller
    wrap = (ja >= 0) & (jb >= 0) & (2 * np.abs(ja - jb) > k)
    lo = np.minimum(ja, jb) + np.where(wrap, k, 0)
    j = (lo + np.maximum(ja, jb)) % (2 * k)
    j = np.where(ja < 0, 2 * jb, j)
    j = np.where(jb < 0, 2 * ja, j)
    return np.stack([r, j], -1)


def dish_pair(values: dict, levels: int, dtype=torch.float64) -> Pair:
    """The body of the dish with these parameter ``values`` at :data:`COARSE` detail, with the exact
    positions of ``levels`` levels of Loop-topology vertices (see the module docstring)."""
    from ipm.generators import get_generator
    from ipm.generators.dishes import resolve_lod
    from ipm.subdiv.halfflap import next_level

    gen = get_generator("dishes")
    values = body_only(gen, values)
    theta, d = gen.split(gen.spec.validate(values), dtype)
    lod = resolve_lod(COARSE)
    coarse = gen.mesh(theta, d, lod)
    n_loops = (coarse.n_verts - 2) // lod.radial
    coords = _grid(n_loops, lod.radial)
    faces = coarse.faces.numpy()
    level_faces = faces
    k = lod.radial
    out = []
    for level in range(1, levels + 1):
        f = 2 ** level
        fine = gen.mesh(theta, d, fine_lod(lod, f)).verts.detach()
        if level == 1:  # every coarse vertex is a vertex of the finer body
            twin = fine[_index(2 * coords, f * (n_loops + 1) - 1, f * k)]
            gap = float((twin - coarse.verts.detach()).abs().max())
            if gap > EXACT:
                raise RuntimeError(f"dishes: a coarse body vertex is {gap:.2e} from its finer twin; the levels "
                                   "of detail no longer nest (see ipm.subdiv.pairs)")
        edges, level_faces = next_level(level_faces, len(coords))
        coords = np.concatenate([2 * coords, _midpoints(coords, edges, k)])
        coords[coords[:, 1] < 0, 1] = -1
        k *= 2
        out.append(fine[_index(coords, f * (n_loops + 1) - 1, k)].to(dtype))
    return Pair(coarse.verts.detach(), faces, tuple(out))


def random_dishes(n: int, rng: np.random.Generator, presets: tuple[str, ...] | None = None) -> list[dict]:
    """``n`` parameter dicts: a preset of the dishes generator (by turns), its continuous parameters moved
    uniformly by up to :data:`SPREAD` of their ranges, without a handle."""
    from ipm.generators import get_generator

    gen = get_generator("dishes")
    names = presets or tuple(sorted(gen.presets))
    unknown = [p for p in names if p not in gen.presets]
    if unknown:
        raise InputError(f"presets: expected dishes presets ({', '.join(sorted(gen.presets))}), got "
                         f"{', '.join(unknown)}")
    out = []
    for i in range(n):
        v = gen.values(names[i % len(names)])
        for p in gen.spec.continuous:
            span = p.hi - p.lo
            v[p.name] = float(np.clip(float(v[p.name]) + rng.uniform(-SPREAD, SPREAD) * span, p.lo, p.hi))
        out.append(body_only(gen, v))
    return out


def body_only(gen, values: dict) -> dict:
    """``values`` with every discrete parameter that adds a part (``Param.adds``) switched off: the body alone."""
    return {**values, **{p.name: 0 for p in gen.spec.discrete if p.adds}}
