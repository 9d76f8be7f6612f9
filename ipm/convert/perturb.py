"""Mesh -> perturbation functions (:mod:`ipm.generators.perturb`), after Vyatkin, Romanyuk and Velichko's
iterative approximation of polygonal models by implicit functions.

Samples. The target (normalized: bounding-box center at the origin, farthest vertex at 1; texture seams
welded) gives on-surface samples ``v`` (its vertices and one random point per face, with unit normals
``n``), where ``F`` should be 0 and ``grad F = n``; the offsets ``v +- eps n``, where ``F`` should be
``+-eps``; and volume samples ``x`` (uniform over the target's box and the base quadric's), with the
truncated signed distance ``s min(d, tau)`` as target (``s`` = +1 outside, -1 inside by the generalized
winding number, ``d`` the distance to the surface; beyond ``tau`` only the sign is asked for). The loss::

    L = sum_v F(v)^2 + sum_v [(F(v + eps n) - eps)^2 + (F(v - eps n) + eps)^2] + w_g sum_v |grad F(v) - n|^2
        + sum_{d(x) <= tau} (F(x) - s min(d, tau))^2 + sum_{d(x) > tau} min(s F(x) - tau, 0)^2

The volume term anchors the scale of ``F`` (without it, least squares would flatten ``F`` towards
zero) and removes stray material away from the surface, which no surface sample sees.

1. Base quadric: the algebraic fit (``B(v) = 0``, the smallest singular vector of the vertex features;
   exact for points on a quadric, so a sphere needs no perturbation) if it is an ellipsoid that already
   meets a tenth of the tolerance; otherwise the least-squares fit of the loss to samples of the convex
   hull (an envelope that ignores cavities, which the perturbations then carve), made an ellipsoid
   (eigenvalues raised to 5% of the largest) and scaled to unit gradient.
2. Perturbations, in rounds, until the mean vertex deviation is at most ``tolerance`` x the bounding-box
   diagonal *and* the mean normal deviation at most ``normal_tolerance`` degrees (for thin walls the
   deviation alone is met too early: a wall's far side passes within the tolerance of a vertex whose
   own side is missing, which only the normals reveal), or ``max_functions`` are used. Each round:

   - seeds: the on-surface samples of largest residual, at least their own residual apart, and the
     volume samples of wrong sign (stray material or holes);
   - placement (the paper's initial approximation of each function at the region of worst fit): at
     every surface seed, spherical and flattened (along the normal) candidates over a ladder of radii
     scaled to the seed's residual, at the seed or half a radius towards the side to change; at a volume
     seed, spheres that stay clear of the surface. Each candidate gets its least-squares amplitude in
     closed form (the loss is quadratic in it but for the one-sided volume rows) and is scored by the
     loss change it brings, on a fixed random third of the samples; the best candidate of each seed is
     kept, and those with the largest gains whose supports do not overlap are added together (the
     batched form of the paper's one-at-a-time loop);
   - refinement: a few Adam steps (the paper's smoothed gradient descent) on the centers, ellipsoid
     matrices and amplitudes of the round's new functions, on the samples near them, all others fixed;
   - whenever the number of functions has grown by a quarter, all amplitudes are refitted jointly by
     linear least squares.

Quality as in the paper: mean and max deviation of the target's vertices from the implicit surface
(``|F| / |grad F|``, the first-order distance; in normalized units and relative to the diagonal) and the
mean angle between vertex normals and ``grad F`` in degrees.
"""

from __future__ import annotations

import logging
import math
import time
from dataclasses import dataclass

import numpy as np
import torch

from ipm.convert import CONVERTERS
from ipm.convert.common import Conversion, Progress, Target, check_positive, check_positive_int, prepare
from ipm.generators.perturb import (
    BASE,
    N_BASE,
    N_PERT,
    PERT,
    PerturbGenerator,
    field,
    param_names,
    quadric_matrix,
    support_radii,
)
from ipm.optim.adam import minimize

log = logging.getLogger(__name__)

RADII = tuple(0.01 * 2.0 ** k for k in range(7))            # 0.01 ... 0.64, a factor 2 apart
OFFSETS = (0.0, 0.5)
FLAT = (1.0, 0.35)                                            # normal radius / tangential radius


# ----------------------------------------------------------------------------------------------
# Quadric features and the base fit
# ----------------------------------------------------------------------------------------------

def _phi(p: np.ndarray) -> np.ndarray:
    """Quadric features ``(N, 10)`` in the order of ``BASE``."""
    x, y, z = p[:, 0], p[:, 1], p[:, 2]
    return np.stack([x * x, y * y, z * z, x * y, x * z, y * z, x, y, z, np.ones_like(x)], 1)


def _grad_phi(p: np.ndarray) -> np.ndarray:
    """Gradients of the features ``(N, 3, 10)``."""
    x, y, z = p[:, 0], p[:, 1], p[:, 2]
    o, one = np.zeros_like(x), np.ones_like(x)
    gx = np.stack([2 * x, o, o, y, z, o, one, o, o, o], 1)
    gy = np.stack([o, 2 * y, o, x, o, z, o, one, o, o], 1)
    gz = np.stack([o, o, 2 * z, o, x, y, o, o, one, o], 1)
    return np.stack([gx, gy, gz], 1)


def _to_ellipsoid(q: np.ndarray, rows: np.ndarray, rhs: np.ndarray) -> np.ndarray:
    """Raise the quadric's eigenvalues to >= 5% of the largest and refit the linear part on ``rows``."""
    M, _, _ = quadric_matrix(q)
    w, U = np.linalg.eigh(M)
    if w.max() <= 0:
        w = np.abs(w)
    if w.min() > 0.05 * w.max():
        return q
    w = np.maximum(w, 0.05 * max(w.max(), 1e-6))
    M2 = (U * w) @ U.T
    quad = np.array([M2[0, 0], M2[1, 1], M2[2, 2], 2 * M2[0, 1], 2 * M2[0, 2], 2 * M2[1, 2]])
    lin, *_ = np.linalg.lstsq(rows[:, 6:], rhs - rows[:, :6] @ quad, rcond=None)
    return np.concatenate([quad, lin])


def fit_base(V: np.ndarray, N: np.ndarray, eps: float, hull: tuple[np.ndarray, np.ndarray] | None = None,
             exact: float = 0.0) -> np.ndarray:
    """Base quadric coefficients ``(10,)`` for vertices ``V (n, 3)`` with unit normals ``N (n, 3)``.

    The algebraic fit (``B(v) = 0``: the smallest right singular vector of the vertex features) is kept
    if it is an ellipsoid whose mean vertex deviation is at most ``exact`` (the mesh is a quadric: a
    sphere needs no perturbation). Otherwise the base is the least-squares fit of the conversion loss to
    ``hull`` (points and outward normals on the convex hull) or, without a hull, to the vertices. Every
    candidate is made an ellipsoid, scaled to a median gradient norm of 1 at the vertices and oriented
    along the normals (negative inside).
    """
    Pon, Gon = _phi(V), _grad_phi(V)

    def rows_of(Vs, Ns):
        rows = np.vstack([_phi(Vs), _phi(Vs + eps * Ns), _phi(Vs - eps * Ns), eps * _grad_phi(Vs).reshape(-1, N_BASE)])
        rhs = np.concatenate([np.zeros(len(Vs)), np.full(len(Vs), eps), np.full(len(Vs), -eps), eps * Ns.reshape(-1)])
        return rows, rhs

    def finish(q, rows, rhs):
        q = _to_ellipsoid(q, rows, rhs)
        G = np.einsum("nkj,j->nk", Gon, q)
        med = float(np.median(np.linalg.norm(G, axis=1)))
        if not med > 1e-12:
            return None, math.inf
        q = q / med * (1.0 if (G * N).sum() > 0 else -1.0)
        G = np.einsum("nkj,j->nk", Gon, q)
        return q, float(np.mean(np.abs(Pon @ q) / np.maximum(np.linalg.norm(G, axis=1), 1e-12)))

    rows, rhs = rows_of(V, N)
    _, _, Vt = np.linalg.svd(Pon, full_matrices=False)
    q_alg, dev_alg = finish(Vt[-1], rows, rhs)
    if q_alg is not None and dev_alg <= exact:
        return q_alg
    if hull is not None:
        rows_h, rhs_h = rows_of(*hull)
        q, _ = finish(np.linalg.lstsq(rows_h, rhs_h, rcond=None)[0], rows_h, rhs_h)
        if q is not None:
            return q
    q_v = np.linalg.lstsq(rows, rhs, rcond=None)[0]
    q, _ = finish(q_v, rows, rhs)
    return q if q is not None else q_v


def _hull_samples(V: np.ndarray, n: int, rng: np.random.Generator) -> tuple[np.ndarray, np.ndarray] | None:
    """``n`` area-weighted points on the convex hull of ``V`` and the outward face normals."""
    from scipy.spatial import ConvexHull
    from scipy.spatial._qhull import QhullError

    try:
        h = ConvexHull(V)
    except QhullError:
        return None
    from ipm.metrics import sample_surface

    pts, fi = sample_surface(V, h.simplices, n, rng, return_faces=True)
    return pts, h.equations[fi, :3]


# ----------------------------------------------------------------------------------------------
# Perturbations on sample pairs (numpy)
# ----------------------------------------------------------------------------------------------
# Perturbations on sample pairs (numpy)
# ----------------------------------------------------------------------------------------------

def _radii(P: np.ndarray) -> np.ndarray:
    """Bounding-ball radii ``(K,)`` of the supports of ``P (K, 10)`` (1 / smallest singular value of A)."""
    return support_radii(P)


def _pairs(tree, centers: np.ndarray, radii: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """All (function k, sample row j) with sample j within ``radii[k]`` of ``centers[k]``."""
    if len(centers) == 0:
        return np.zeros(0, np.int64), np.zeros(0, np.int64)
    found = tree.query_ball_point(centers, radii * (1 + 1e-9) + 1e-12, return_sorted=False)
    sizes = np.fromiter((len(f) for f in found), dtype=np.int64, count=len(found))
    rows = np.concatenate([np.asarray(f, dtype=np.int64) for f in found]) if sizes.sum() else np.zeros(0, np.int64)
    return np.repeat(np.arange(len(centers)), sizes), rows


def _unit_bump(P: np.ndarray, k: np.ndarray, X: np.ndarray, grad: bool = False):
    """Unit-amplitude values ``R (m,)`` (and gradients ``(m, 3)``) of functions ``P[k]`` at points ``X (m, 3)``:
    ``R = max(Q, 0)^3``, ``grad R = -6 max(Q, 0)^2 A^T A (p - c)``."""
    Pk = P[k]
    d = X - Pk[:, :3]
    u0 = Pk[:, 3] * d[:, 0] + Pk[:, 4] * d[:, 1] + Pk[:, 5] * d[:, 2]
    u1 = Pk[:, 6] * d[:, 1] + Pk[:, 7] * d[:, 2]
    u2 = Pk[:, 8] * d[:, 2]
    Q = np.maximum(1.0 - (u0 * u0 + u1 * u1 + u2 * u2), 0.0)
    R = Q * Q * Q
    if not grad:
        return R, None
    g = np.stack([Pk[:, 3] * u0, Pk[:, 4] * u0 + Pk[:, 6] * u1, Pk[:, 5] * u0 + Pk[:, 7] * u1 + Pk[:, 8] * u2], 1)
    return R, (-6.0 * Q * Q)[:, None] * g


def _cholesky_upper(M: np.ndarray) -> np.ndarray:
    """Upper-triangular ``A (..., 3, 3)`` with ``A^T A = M`` for symmetric positive definite ``M``."""
    return np.swapaxes(np.linalg.cholesky(M), -1, -2)


def _frame(n: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Two unit tangents ``(K, 3)`` each, orthogonal to unit normals ``n (K, 3)``."""
    a = np.where(np.abs(n[:, :1]) < 0.9, np.array([[1.0, 0, 0]]), np.array([[0, 1.0, 0]]))
    t1 = np.cross(n, a)
    t1 /= np.linalg.norm(t1, axis=1, keepdims=True)
    return t1, np.cross(n, t1)


@dataclass
class _State:
    """Samples, targets and the current field (float64 numpy).

    Rows of ``X (M, 3)``: ``S`` on-surface samples (the ``n`` target vertices first, then one point per
    face) with unit normals ``normals (S, 3)``; their offsets ``+ eps n`` and ``- eps n`` (targets ``t``);
    then volume samples with targets ``t = s min(d, tau)`` (``s`` = +1 outside, -1 inside, ``d`` the
    distance ``d`` to the surface): squared residuals where ``d <= tau``, one-sided (``s F >= tau``) on the
    ``hinge`` rows beyond. ``G`` is the field's gradient at the on-surface samples; ``wg`` weighs the
    gradient term of the loss.
    """

    X: np.ndarray
    t: np.ndarray
    s: np.ndarray
    d: np.ndarray
    hinge: np.ndarray
    normals: np.ndarray
    n: int
    S: int
    wg: float
    F: np.ndarray
    G: np.ndarray

    @property
    def n_surf(self) -> int:
        """Rows of ``X`` with surface targets: the ``S`` on-surface samples and their two offsets."""
        return 3 * self.S

    def residual(self, rows: np.ndarray, F: np.ndarray) -> np.ndarray:
        """Residuals at ``rows`` for field values ``F`` there (zero on satisfied hinge rows)."""
        r = F - self.t[rows]
        h = self.hinge[rows]
        r[h] = np.minimum(self.s[rows[h]] * r[h], 0.0)
        return r

    def total_loss(self) -> float:
        """The whole loss: squared residuals over every row plus ``wg`` times ``|G - normals|^2``."""
        r = self.residual(np.arange(len(self.X)), self.F)
        g = self.G - self.normals
        return float((r * r).sum() + self.wg * (g * g).sum())

    def deviation(self) -> np.ndarray:
        """First-order distance ``|F| / |grad F|`` ``(S,)`` of the on-surface samples from the zero set."""
        return np.abs(self.F[: self.S]) / np.maximum(np.linalg.norm(self.G, axis=1), 1e-12)

    def errors(self) -> np.ndarray:
        """Largest residual ``(S,)`` of each on-surface sample and its two offsets (in field units, which
        the loss keeps close to distances). Unlike the deviation it also sees a surface facing the
        wrong way (a thin wall whose other side passes near the sample)."""
        r = np.abs(self.F[: self.n_surf] - self.t[: self.n_surf]).reshape(3, self.S)
        return r.max(0)

    def normal_angles(self) -> np.ndarray:
        """Angles in degrees ``(n,)`` between ``grad F`` and the normals at the target vertices."""
        G = self.G[: self.n]
        cos = (G * self.normals[: self.n]).sum(1) / np.maximum(np.linalg.norm(G, axis=1), 1e-12)
        return np.degrees(np.arccos(np.clip(cos, -1.0, 1.0)))


def _evaluate(st: _State, tree, q: np.ndarray, P: np.ndarray) -> None:
    """Recompute ``F`` at every row and ``grad F`` at the on-surface samples from scratch."""
    st.F = _phi(st.X) @ q
    st.G = np.einsum("nkj,j->nk", _grad_phi(st.X[: st.S]), q)
    _add(st, tree, P)


def _add(st: _State, tree, P: np.ndarray) -> None:
    """Add the contributions of functions ``P (K, 10)`` to ``F`` and ``G``."""
    if len(P) == 0:
        return
    k, rows = _pairs(tree, P[:, :3], _radii(P))
    R, _ = _unit_bump(P, k, st.X[rows])
    np.add.at(st.F, rows, P[k, 9] * R)
    on = rows < st.S
    _, g = _unit_bump(P, k[on], st.X[rows[on]], grad=True)
    np.add.at(st.G, rows[on], P[k[on], 9, None] * g)


# ----------------------------------------------------------------------------------------------
# One round: seeds, candidates, refinement
# ----------------------------------------------------------------------------------------------

def _seeds(st: _State, dev: np.ndarray, k: int, tabu: np.ndarray, floor: float, spacing: float) -> np.ndarray:
    """Up to ``k`` on-surface samples of worst error ``dev (S,)`` (above ``floor``), each at least its own
    error (and ``spacing``) away from the seeds already taken."""
    order = np.argsort(-np.where(tabu, -1.0, dev))
    chosen: list[int] = []
    for v in order[: 50 * k]:
        if dev[v] <= floor or tabu[v]:
            break
        if chosen:
            d = np.linalg.norm(st.X[chosen] - st.X[v], axis=1)
            if (d < np.maximum(np.maximum(dev[chosen], dev[v]), spacing)).any():
                continue
        chosen.append(int(v))
        if len(chosen) >= k:
            break
    return np.asarray(chosen, dtype=np.int64)


def _candidates(st: _State, seeds: np.ndarray, dev: np.ndarray, r_min: float) -> tuple[np.ndarray, np.ndarray]:
    """Candidate functions ``(C, 10)`` (amplitude 0) around each seed, and their seed index ``(C,)``:
    radii from the ladder ``RADII`` between half and six times the seed's error (at least
    ``r_min``), spherical or flattened along the normal, at the seed or half a normal radius towards
    the side to change."""
    v, n = st.X[seeds], st.normals[seeds]
    side = np.where(st.F[seeds] > 0, 1.0, -1.0)          # F > 0: add material, so lean inwards
    t1, t2 = _frame(n)
    ladder = np.array([r for r in RADII if r >= r_min] or [r_min])
    rows, owner = [], []
    for i in range(len(seeds)):
        lo, hi = 0.5 * dev[seeds[i]], 6.0 * dev[seeds[i]] + 2 * r_min
        radii = ladder[(ladder >= lo) & (ladder <= hi)]
        if len(radii) == 0:
            radii = ladder[[int(np.argmin(np.abs(ladder - lo)))]]
        for r in radii:
            for flat in FLAT:
                rn = r * flat
                M = np.outer(n[i], n[i]) / rn ** 2 + (np.outer(t1[i], t1[i]) + np.outer(t2[i], t2[i])) / r ** 2
                A = _cholesky_upper(M)
                for off in OFFSETS:
                    c = v[i] - side[i] * off * rn * n[i]
                    rows.append([*c, A[0, 0], A[0, 1], A[0, 2], A[1, 1], A[1, 2], A[2, 2], 0.0])
                    owner.append(i)
    return np.asarray(rows, dtype=np.float64).reshape(-1, N_PERT), np.asarray(owner, dtype=np.int64)


def _volume_seeds(st: _State, k: int, floor: float) -> np.ndarray:
    """Up to ``k`` volume rows whose sign is wrong by more than ``floor`` (stray material or holes away
    from the surface, which no surface sample sees), each outside the others' reach (their distances
    to the surface)."""
    vol = np.arange(st.n_surf, len(st.X))
    r = np.abs(st.residual(vol, st.F[vol]))
    wrong = st.s[vol] * st.F[vol] < 0
    order = vol[np.argsort(-np.where(wrong, r, -1.0))]
    chosen: list[int] = []
    for j in order[: 50 * k]:
        if not (st.s[j] * st.F[j] < 0) or abs(st.F[j] - st.t[j]) <= floor:
            break
        if chosen and (np.linalg.norm(st.X[chosen] - st.X[j], axis=1) < st.d[chosen] + st.d[j]).any():
            continue
        chosen.append(int(j))
        if len(chosen) >= k:
            break
    return np.asarray(chosen, dtype=np.int64)


def _volume_candidates(st: _State, seeds: np.ndarray, owner0: int) -> tuple[np.ndarray, np.ndarray]:
    """Spheres centered at volume seeds, of radii 0.9 and 0.6 times the seed's distance to the surface
    (so they do not move the surface), and their owners ``owner0 + i``."""
    rows, owner = [], []
    for i, j in enumerate(seeds):
        for frac in (0.9, 0.6):
            a = 1.0 / (frac * st.d[j])
            rows.append([*st.X[j], a, 0.0, 0.0, a, 0.0, a, 0.0])
            owner.append(owner0 + i)
    return np.asarray(rows, dtype=np.float64).reshape(-1, N_PERT), np.asarray(owner, dtype=np.int64)


def _score(st: _State, tree, C: np.ndarray, subset: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray]:
    """Closed-form amplitudes ``(K,)`` of candidates ``C (K, 10)`` (least squares of the surface and
    gradient terms over their supports) and the loss change ``(K,)`` each brings, volume term included.
    With ``subset`` (row indices; ``tree`` is then built on those rows) only those rows are used: a
    cheaper ranking of many candidates."""
    k, rows = _pairs(tree, C[:, :3], _radii(C))
    if subset is not None:
        rows = subset[rows]
    K = len(C)
    surf = ~st.hinge[rows]                   # rows with squared residuals (surface and near volume)
    on = rows < st.S
    R, _ = _unit_bump(C, k, st.X[rows])
    _, gR = _unit_bump(C, k[on], st.X[rows[on]], grad=True)
    r = st.F[rows] - st.t[rows]
    ge = st.G[rows[on]] - st.normals[rows[on]]
    a = (np.bincount(k[surf], weights=R[surf] ** 2, minlength=K)
         + st.wg * np.bincount(k[on], weights=(gR * gR).sum(1), minlength=K))
    b = (np.bincount(k[surf], weights=(R * r)[surf], minlength=K)
         + st.wg * np.bincount(k[on], weights=(gR * ge).sum(1), minlength=K))
    ok = a > 1e-300
    f = np.where(ok, -b / np.where(ok, a, 1.0), 0.0)
    gain = np.where(ok, -b * b / np.where(ok, a, 1.0), 0.0)
    vol = ~surf
    if vol.any():
        rv, kv = rows[vol], k[vol]
        before = np.minimum(st.s[rv] * (st.F[rv] - st.t[rv]), 0.0) ** 2
        after = np.minimum(st.s[rv] * (st.F[rv] + f[kv] * R[vol] - st.t[rv]), 0.0) ** 2
        gain += np.bincount(kv, weights=after - before, minlength=K)
    return f, gain


def _pick(C: np.ndarray, owner: np.ndarray, gain: np.ndarray, k: int) -> tuple[np.ndarray, np.ndarray]:
    """The best candidate of each seed, then the largest gains with disjoint supports (up to ``k``).
    Returns the chosen functions ``(k', 10)`` (amplitude 0) and the seeds that have no candidate lowering
    the loss."""
    best: dict[int, int] = {}
    for i in np.argsort(gain):
        if gain[i] >= 0:
            break
        best.setdefault(int(owner[i]), int(i))
    idx = sorted(best.values(), key=lambda i: gain[i])
    radii = _radii(C)
    chosen: list[int] = []
    for i in idx:
        if chosen:
            d = np.linalg.norm(C[chosen, :3] - C[i, :3], axis=1)
            if (d < radii[chosen] + radii[i]).any():
                continue
        chosen.append(i)
        if len(chosen) >= k:
            break
    out = C[chosen].copy()
    hopeless = np.setdiff1d(np.unique(owner), np.fromiter(best, dtype=np.int64, count=len(best)))
    return out, hopeless


def _refine(st: _State, tree, P0: np.ndarray, steps: int, lr: float) -> np.ndarray:
    """Adam on the functions ``P0 (K, 10)`` jointly (all others fixed) over the samples within 1.5 times
    their supports; parameters are scaled (centers by the radius, ``A`` by 1 / radius, amplitudes by
    their size) so one learning rate suits all. Returns the best functions seen (never worse than
    ``P0`` on those samples)."""
    rad = _radii(P0)
    k, rows = _pairs(tree, P0[:, :3], 1.5 * rad)
    if len(rows) == 0 or steps <= 0:
        return P0
    own, _ = _unit_bump(P0, k, st.X[rows])
    on = rows < st.S
    _, gown = _unit_bump(P0, k[on], st.X[rows[on]], grad=True)
    # a row may lie in several supports: the field there sums their contributions
    urows, inv = np.unique(rows, return_inverse=True)
    inv = inv.reshape(-1)
    uon = urows < st.S
    won = np.flatnonzero(uon)
    gpos = np.full(len(urows), -1)
    gpos[won] = np.arange(len(won))
    ubase = st.F[urows] - np.bincount(inv, weights=P0[k, 9] * own, minlength=len(urows))
    gbase = st.G[urows[uon]].copy()
    np.add.at(gbase, gpos[inv[on]], -P0[k[on], 9, None] * gown)
    T = torch.from_numpy
    X, kt, inv_t = T(st.X[rows]), T(k), T(inv)
    on_t, ginv = T(on), T(gpos[inv[on]])
    ubase_t, gbase_t, gn = T(ubase), T(gbase), T(st.normals[urows[uon]])
    ut, us, uh = T(st.t[urows]), T(st.s[urows]), T(st.hinge[urows])
    scale = np.concatenate([np.repeat(rad[:, None], 3, 1), np.repeat(1.0 / rad[:, None], 6, 1),
                            np.maximum(np.abs(P0[:, 9:]), 1e-6)], 1)
    scale_t, P0t = T(scale), T(P0)

    def objective(P: torch.Tensor) -> torch.Tensor:
        Pk = P[kt]
        d = X - Pk[:, :3]
        u0 = Pk[:, 3] * d[:, 0] + Pk[:, 4] * d[:, 1] + Pk[:, 5] * d[:, 2]
        u1 = Pk[:, 6] * d[:, 1] + Pk[:, 7] * d[:, 2]
        u2 = Pk[:, 8] * d[:, 2]
        Q = torch.relu(1.0 - (u0 * u0 + u1 * u1 + u2 * u2))
        F = ubase_t.index_add(0, inv_t, Q * Q * Q * Pk[:, 9])
        res = torch.where(uh, torch.clamp(us * (F - ut), max=0.0), F - ut)
        g = torch.stack([Pk[:, 3] * u0, Pk[:, 4] * u0 + Pk[:, 6] * u1,
                         Pk[:, 5] * u0 + Pk[:, 7] * u1 + Pk[:, 8] * u2], 1)
        g = (-6.0 * Q * Q * Pk[:, 9])[:, None] * g
        G = gbase_t.index_add(0, ginv, g[on_t]) - gn
        return (res * res).sum() + st.wg * (G * G).sum()

    z = torch.zeros_like(P0t, requires_grad=True)
    best = {"P": P0t.clone(), "loss": math.inf}

    def loss_fn(step: int) -> torch.Tensor:
        P = P0t + scale_t * z
        loss = objective(P)
        if float(loss.detach()) < best["loss"]:
            best.update(P=P.detach().clone(), loss=float(loss.detach()))
        return loss

    minimize([z], loss_fn, steps + 1, lr)
    out = best["P"].numpy()
    # a function grown past the samples it was refined on would act where it was not checked
    grown = _radii(out) > 1.5 * rad
    out[grown] = P0[grown]
    return out


def refit_linear(st: _State, tree, q: np.ndarray, P: np.ndarray, *, base: bool = False, ridge: float = 1e-9,
                 rounds: int = 2) -> tuple[np.ndarray, np.ndarray]:
    """Joint least-squares refit of every amplitude (and, with ``base``, of the base coefficients): the
    field and its gradient are linear in them; centers and shapes stay. The active set of the
    one-sided volume rows is updated ``rounds`` times. Returns ``(q (10,), P (K, 10))``.

    The base is held by default: it sets the field's scale, and refitting it with the amplitudes lets
    least squares shrink the whole field towards zero (every residual shrinks with it)."""
    import scipy.sparse as sp

    M, S = len(st.X), st.S
    k, rows = _pairs(tree, P[:, :3], _radii(P))
    unit = P.copy()
    unit[:, 9] = 1.0
    R, _ = _unit_bump(unit, k, st.X[rows])
    on = rows < S
    _, gR = _unit_bump(unit, k[on], st.X[rows[on]], grad=True)
    w = math.sqrt(st.wg)
    grow = (M + 3 * rows[on][:, None] + np.arange(3)[None]).reshape(-1)
    A_val = sp.csr_matrix((np.concatenate([R, w * gR.reshape(-1)]),
                           (np.concatenate([rows, grow]), np.concatenate([k, np.repeat(k[on], 3)]))),
                          shape=(M + 3 * S, len(P)))
    A_base = np.vstack([_phi(st.X), w * _grad_phi(st.X[:S]).reshape(-1, N_BASE)])
    tgt = np.concatenate([st.t, w * st.normals.reshape(-1)])
    if base:
        A_full, coef = sp.hstack([sp.csr_matrix(A_base), A_val]).tocsr(), np.concatenate([q, P[:, 9]])
    else:
        A_full, coef, tgt = A_val, P[:, 9].copy(), tgt - A_base @ q
    offset = 0.0 if base else (A_base @ q)[:M]
    for _ in range(rounds):
        F = A_full[:M] @ coef + offset
        act = np.concatenate([~st.hinge | (st.s * (F - st.t) < 0), np.ones(3 * S, bool)]).astype(np.float64)
        A = sp.diags(act) @ A_full
        AtA = (A.T @ A).toarray()
        AtA[np.diag_indices_from(AtA)] += ridge * max(float(np.trace(AtA)) / len(AtA), 1e-12)
        try:
            coef = np.linalg.solve(AtA, A.T @ (act * tgt))
        except np.linalg.LinAlgError:
            return q, P
    P2 = P.copy()
    if base:
        P2[:, 9] = coef[N_BASE:]
        return coef[:N_BASE], P2
    P2[:, 9] = coef
    return q.copy(), P2


# ----------------------------------------------------------------------------------------------
# The conversion
# ----------------------------------------------------------------------------------------------

def quality(q: np.ndarray, P: np.ndarray, target: Target) -> dict:
    """The paper's quality measures at the target's vertices: mean and max deviation from the implicit
    surface ``|F| / |grad F|`` (the first-order distance; normalized units, and relative to the
    bounding-box diagonal) and the mean angle in degrees between vertex normals and ``grad F``,
    computed with the generator's field and autograd (independently of the converter's bookkeeping)."""
    n = len(P)
    th = torch.from_numpy(np.concatenate([q, P.reshape(-1)]))
    X = torch.from_numpy(target.verts).requires_grad_(True)
    F = field(th, X, n)
    (G,) = torch.autograd.grad(F.sum(), X)
    F, G = F.detach().numpy(), G.numpy()
    gn = np.linalg.norm(G, axis=1)
    dev = np.abs(F) / np.maximum(gn, 1e-12)
    cos = np.clip((G * target.normals).sum(1) / np.maximum(gn, 1e-12), -1.0, 1.0)
    diag = target.diagonal
    return {"mean_deviation": float(dev.mean()), "max_deviation": float(dev.max()),
            "mean_deviation_rel": float(dev.mean() / diag), "max_deviation_rel": float(dev.max() / diag),
            "mean_normal_deviation_deg": float(np.degrees(np.arccos(cos)).mean()),
            "diagonal": diag, "vertices": len(target.verts)}


def _face_samples(target: Target, n: int, rng: np.random.Generator) -> tuple[np.ndarray, np.ndarray]:
    """Surface points ``(m, 3)`` and their unit face normals: one per face (uniform barycentrics), or
    ``n`` area-weighted ones if the mesh has fewer than ``n`` faces (a low-poly mesh would otherwise
    leave its big faces unwatched)."""
    if len(target.faces) >= n:
        t = target.verts[target.faces]
        fn = np.cross(t[:, 1] - t[:, 0], t[:, 2] - t[:, 0])
        fn /= np.maximum(np.linalg.norm(fn, axis=1, keepdims=True), 1e-300)
        u, v = rng.random(len(t)), rng.random(len(t))
        flip = u + v > 1
        u[flip], v[flip] = 1 - u[flip], 1 - v[flip]
        return t[:, 0] + u[:, None] * (t[:, 1] - t[:, 0]) + v[:, None] * (t[:, 2] - t[:, 0]), fn
    from ipm.convert.common import surface_with_normals

    return surface_with_normals(target, n, rng)


@CONVERTERS.register("perturb")
def convert_perturb(mesh, *, max_functions: int = 2000, tolerance: float = 0.01, progress: Progress | None = None,
                    normal_tolerance: float = 20.0, seed: int = 0, eps: float | None = None,
                    truncation: float = 0.03, normal_weight: float = 4.0, volume_samples: int = 20_000,
                    surface_samples: int = 8000, steps: int = 5, lr: float = 0.05, refit_growth: float = 1.25,
                    score_share: float = 0.35,
                    time_limit: float | None = None) -> Conversion:
    """Convert ``mesh`` (TriMesh, trimesh or (V, F)) to a base quadric plus perturbations (module docstring).

    max_functions: at most this many perturbations (>= 1); tolerance: stop when the mean vertex
    deviation is at most this share of the bounding-box diagonal (> 0) and the mean normal deviation
    at most ``normal_tolerance`` degrees (180 turns that test off); eps: offset of the off-surface
    samples (default 0.25% of the diagonal); truncation: ``tau`` of the volume targets, as a share of
    the diagonal; normal_weight: weight of the gradient term, times ``eps^2``; volume_samples: uniform
    samples labelled inside/outside; surface_samples: at least this many on-surface samples besides
    the vertices; steps, lr: Adam refinement of each round's new functions; refit_growth: refit all
    amplitudes jointly whenever the number of functions has grown by this factor since the last refit
    (0: never); score_share: share of the samples candidates are ranked on; time_limit: stop after this
    many seconds.
    progress(done, max_functions, info) is called after every round.

    Returns a :class:`~ipm.convert.common.Conversion` with a :class:`PerturbGenerator`; ``stats`` holds
    ``functions`` (perturbations used), ``parameters``, the :func:`quality` measures, ``reached`` (both
    tolerances met), ``rounds`` and ``seconds``. The result lives in the normalized frame.
    """
    max_functions = check_positive_int("max_functions", max_functions)
    tolerance = check_positive("tolerance", tolerance)
    normal_tolerance = check_positive("normal_tolerance", normal_tolerance)
    if eps is not None:
        eps = check_positive("eps", eps)
    from scipy.spatial import cKDTree

    t0 = time.perf_counter()
    rng = np.random.default_rng(seed)
    target = prepare(mesh)
    V, N = target.verts, target.normals
    n = len(V)
    diag = target.diagonal
    eps = eps if eps is not None else 0.0025 * diag
    goal = tolerance * diag
    q = fit_base(V, N, eps, _hull_samples(V, min(4 * n, 20_000), rng), exact=0.1 * goal)
    st = _sampled_state(target, q, eps, rng, surface_samples=surface_samples, volume_samples=volume_samples,
                        truncation=truncation, normal_weight=normal_weight)
    tree = cKDTree(st.X)
    subset = np.sort(rng.choice(len(st.X), size=max(1, int(score_share * len(st.X))), replace=False))
    tree_sub = cKDTree(st.X[subset])
    # no function smaller than a few sample spacings: it could fit the samples and miss the surface between
    tri = V[target.faces]
    area = 0.5 * float(np.linalg.norm(np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0]), axis=1).sum())
    r_min = max(2.5 * math.sqrt(area / st.S), 4 * eps)
    q, P, rounds = _rounds(st, tree, tree_sub, subset, q, goal=goal, diag=diag, normal_tolerance=normal_tolerance,
                           r_min=r_min, max_functions=max_functions, steps=steps, lr=lr, refit_growth=refit_growth,
                           time_limit=time_limit, t0=t0, progress=progress)
    stats = {"functions": len(P), "parameters": N_BASE + N_PERT * len(P), **quality(q, P, target)}
    stats["reached"] = bool(stats["mean_deviation"] <= goal and stats["mean_normal_deviation_deg"] <= normal_tolerance)
    stats["tolerance"] = tolerance
    stats["normal_tolerance"] = normal_tolerance
    stats["rounds"] = rounds
    stats["seconds"] = time.perf_counter() - t0
    return _conversion(q, P, target, seed, stats)


def _sampled_state(target: Target, q: np.ndarray, eps: float, rng: np.random.Generator, *, surface_samples: int,
                   volume_samples: int, truncation: float, normal_weight: float) -> _State:
    """The samples and targets of the loss (module docstring) as a :class:`_State` whose field is not yet
    evaluated: the vertices and ``surface_samples`` face points with their ``eps`` offsets, and volume
    samples over the target's box and the base quadric ``q``'s (the base puts material there too), those
    within ``2 eps`` of the surface dropped."""
    from ipm.metrics import inside, point_to_surface

    V, N = target.verts, target.normals
    n = len(V)
    diag = target.diagonal
    Fp, Fn = _face_samples(target, surface_samples, rng)
    On, On_n = np.vstack([V, Fp]), np.vstack([N, Fn])
    S = len(On)
    lo, hi = V.min(0) - 0.05 * diag, V.max(0) + 0.05 * diag
    blo, bhi = PerturbGenerator(0, dict(zip(param_names(0), q.tolist()))).tree.bounds()
    lo, hi = np.minimum(lo, blo), np.maximum(hi, bhi)          # wherever the base puts material, too
    vol = rng.uniform(lo, hi, size=(volume_samples, 3))
    dist = point_to_surface(vol, V, target.faces)
    keep = dist > 2 * eps
    vol, dist = vol[keep], dist[keep]
    sv = np.where(inside(vol, V, target.faces), -1.0, 1.0)
    X = np.vstack([On, On + eps * On_n, On - eps * On_n, vol])
    tau = truncation * diag
    return _State(X, np.concatenate([np.zeros(S), np.full(S, eps), np.full(S, -eps), sv * np.minimum(dist, tau)]),
                  np.concatenate([np.zeros(3 * S), sv]), np.concatenate([np.zeros(3 * S), dist]),
                  np.concatenate([np.zeros(3 * S, bool), dist > tau]),
                  On_n, n, S, normal_weight * eps * eps, np.zeros(len(X)), np.zeros((S, 3)))


def _rounds(st: _State, tree, tree_sub, subset: np.ndarray, q: np.ndarray, *, goal: float, diag: float,
            normal_tolerance: float, r_min: float, max_functions: int, steps: int, lr: float, refit_growth: float,
            time_limit: float | None, t0: float, progress: Progress | None) -> tuple[np.ndarray, np.ndarray, int]:
    """The rounds of step 2 of the module docstring, from the base quadric ``q`` (10,) alone until both
    tolerances are met (mean vertex deviation ``goal``, mean normal deviation ``normal_tolerance``
    degrees), ``max_functions`` are used, ``time_limit`` seconds since ``t0`` have passed or no seed is
    left. ``tree`` indexes all samples, ``tree_sub`` the ``subset`` candidates are ranked on. Returns the
    base (10,), the perturbations (P, N_PERT) and the rounds run, float64."""
    n = st.n
    P = np.zeros((0, N_PERT))
    _evaluate(st, tree, q, P)
    tabu = np.zeros(st.S, dtype=bool)
    log.info("perturb: base quadric, mean deviation %.4g (goal %.4g)", st.deviation()[:n].mean(), goal)
    rounds, refitted = 0, 4

    def done() -> bool:
        return bool(st.deviation()[:n].mean() <= goal and st.normal_angles().mean() <= normal_tolerance)

    while len(P) < max_functions and not done():
        if time_limit is not None and time.perf_counter() - t0 > time_limit:
            break
        rounds += 1
        k = int(min(max_functions - len(P), max(4, min(96, len(P) // 3))))
        err = st.errors()
        seeds = _seeds(st, err, 2 * k, tabu, floor=0.25 * goal, spacing=r_min)
        if len(seeds) == 0 and not len(_volume_seeds(st, 1, floor=0.25 * goal)):
            if tabu.any():
                tabu[:] = False
                continue
            break
        C, owner = _candidates(st, seeds, err, r_min)
        vseeds = _volume_seeds(st, max(1, k // 4), floor=0.25 * goal)
        if len(vseeds):
            Cv, ov = _volume_candidates(st, vseeds, len(seeds))
            C, owner = np.vstack([C, Cv]), np.concatenate([owner, ov])
        _, gain = _score(st, tree_sub, C, subset)
        new, hopeless = _pick(C, owner, gain, k)
        hopeless = hopeless[hopeless < len(seeds)]
        tabu[seeds[hopeless]] = True                      # no candidate helps there: try elsewhere first
        if len(new) == 0:
            continue
        new[:, 9], _ = _score(st, tree, new)              # the amplitudes on all samples
        new = _refine(st, tree, new, steps, lr)
        _add(st, tree, new)
        P = np.vstack([P, new])
        if refit_growth and len(P) >= refit_growth * refitted:
            refitted = len(P)
            q, P = _refit_if_better(st, tree, q, P)
        if progress is not None:
            progress(len(P), max_functions, {"mean_deviation_rel": float(st.deviation()[:n].mean() / diag),
                                             "normal_deg": float(st.normal_angles().mean()), "rounds": rounds})
    return q, P, rounds


def _refit_if_better(st: _State, tree, q: np.ndarray, P: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """All amplitudes refitted jointly (:func:`refit_linear`): the refit base and perturbations if they lower
    the total loss (``st`` then holds their field), else ``q`` and ``P`` with ``st``'s field as it was."""
    before, saved = st.total_loss(), (st.F.copy(), st.G.copy())
    q2, P2 = refit_linear(st, tree, q, P)
    _evaluate(st, tree, q2, P2)
    if st.total_loss() < before:
        return q2, P2
    st.F, st.G = saved
    return q, P


def _conversion(q: np.ndarray, P: np.ndarray, target: Target, seed: int, stats: dict) -> Conversion:
    """The :class:`PerturbGenerator` of base ``q`` (10,) and perturbations ``P`` (P, N_PERT), with its file
    (the conversion's ``stats`` and the target's frame) as a :class:`Conversion`."""
    values = dict(zip(param_names(len(P)), np.concatenate([q, P.reshape(-1)]).tolist()))
    gen = PerturbGenerator(len(P), values)
    vals = gen.spec.defaults()
    data = gen.to_json(vals, conversion={"method": "perturb", "seed": seed, **stats},
                       frame={"center": target.center.tolist(), "scale": target.scale})
    log.info("perturb: %d functions, mean deviation %.3g%% of the diagonal in %.1f s", len(P),
             100 * stats["mean_deviation_rel"], stats["seconds"])
    return Conversion(gen, vals, data, stats)


__all__ = ["BASE", "PERT", "convert_perturb", "fit_base", "quality", "refit_linear"]
