"""Perturbation functions: a base quadric plus compactly supported perturbations (Vyatkin, Romanyuk,
Velichko: iterative approximation of polygonal models by implicit functions; the representation goes
back to Pasko and Savchenko's function representation and to Vyatkin's "free forms").

The field, negative inside::

    F(p) = B(p) + sum_i f_i R_i(p),      R_i(p) = Q_i(p)^3 if Q_i(p) >= 0 else 0,      Q_i(p) = 1 - |A_i (p - c_i)|^2

- ``B(p) = xx x^2 + yy y^2 + zz z^2 + xy x y + xz x z + yz y z + x x + y y + z z + c``: a general quadric
  (10 coefficients; a sphere ``(|p|^2 - r^2) / (2 r)`` is one).
- Perturbation ``i``: center ``c_i`` (3), an upper-triangular ``A_i`` (6: ``a00 a01 a02 a11 a12 a22``;
  ``A^T A`` is any ellipsoid (Cholesky), so upper-triangular loses nothing) and amplitude ``f_i``. The
  perturbing quadric ``Q_i`` is positive inside the ellipsoid ``|A_i (p - c_i)| <= 1``; ``R_i`` vanishes
  outside it together with its first and second derivatives (C2, the paper's ``R = Q^3``). ``f_i > 0``
  removes material, ``f_i < 0`` adds it. The paper writes ``F = F_0 + sum f_i R_i`` with the solid where
  ``F >= 0``; ours is its negative.

``F`` is not a distance (conversion makes it behave like one near the surface), so it is no bound for
sphere tracing or narrow-band meshing: :meth:`PerturbGenerator.to_mesh` runs marching cubes over a full
grid. Evaluation is exact and sparse for large inputs: each perturbation only touches the points
inside its bounding ball (a k-d tree query); small inputs and inputs under ``torch.func`` transforms
(``jacfwd``, ``vmap``) take the dense path, which gives the same values.

A file (``{"generator": "perturb", "perturbations": N, "extent": E, "params": {...}}``) loads with
:meth:`PerturbGenerator.from_file`, ``get_generator(path)`` and ``ipm generate path``.
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from pathlib import Path

import numpy as np
import torch

from ipm.errors import InputError
from ipm.generators.base import Generator, ValuesField, check_field_meshing, check_format, register_generator
from ipm.params import Param, ParamSpec, Value
from ipm.types import TriMesh

FORMAT = "perturb"
BASE = ("xx", "yy", "zz", "xy", "xz", "yz", "x", "y", "z", "c")
PERT = ("cx", "cy", "cz", "a00", "a01", "a02", "a11", "a12", "a22", "f")
N_BASE, N_PERT = len(BASE), len(PERT)
DENSE_BUDGET = 1 << 21     # points x perturbations evaluated densely per chunk
SPARSE_CHUNK = 1 << 18     # points per chunk of the sparse path


def param_names(n: int) -> list[str]:
    """Names of the base coefficients then of ``n`` perturbations: ``base.<k>``, ``p<i>.<k>``."""
    return [f"base.{k}" for k in BASE] + [f"p{i}.{k}" for i in range(n) for k in PERT]


def quadric(q: torch.Tensor, p: torch.Tensor) -> torch.Tensor:
    """Base quadric ``(...)`` at ``p (..., 3)`` for coefficients ``q (10,)`` (order of ``BASE``)."""
    x, y, z = p[..., 0], p[..., 1], p[..., 2]
    return (q[0] * x * x + q[1] * y * y + q[2] * z * z + q[3] * x * y + q[4] * x * z + q[5] * y * z
            + q[6] * x + q[7] * y + q[8] * z + q[9])


def bump_values(P: torch.Tensor, d: torch.Tensor) -> torch.Tensor:
    """``f max(Q, 0)^3`` for perturbations ``P (..., 10)`` at offsets ``d = p - c (..., 3)`` (broadcast)."""
    u0 = P[..., 3] * d[..., 0] + P[..., 4] * d[..., 1] + P[..., 5] * d[..., 2]
    u1 = P[..., 6] * d[..., 1] + P[..., 7] * d[..., 2]
    u2 = P[..., 8] * d[..., 2]
    Q = torch.relu(1.0 - (u0 * u0 + u1 * u1 + u2 * u2))
    return Q * Q * Q * P[..., 9]


def bumps(P: torch.Tensor, p: torch.Tensor) -> torch.Tensor:
    """``sum_i f_i R_i`` ``(...)`` at ``p (..., 3)`` for perturbations ``P (N, 10)`` (order of ``PERT``), dense."""
    return bump_values(P, p[..., None, :] - P[:, :3]).sum(-1)


def support_radii(P: np.ndarray) -> np.ndarray:
    """Radii ``(N,)`` of balls around the centers containing each support ``|A (p - c)| <= 1``:
    ``1 / sigma_min(A)`` (inf for a singular ``A``)."""
    s = np.linalg.svd(upper(P), compute_uv=False)[:, -1] if len(P) else np.zeros(0)
    return np.where(s > 1e-12, 1.0 / np.maximum(s, 1e-300), np.inf)


def _is_transformed(t: torch.Tensor) -> bool:
    from torch._C._functorch import is_functorch_wrapped_tensor

    return bool(is_functorch_wrapped_tensor(t))


def _sparse_bumps(P: torch.Tensor, points: torch.Tensor) -> torch.Tensor:
    """``sum_i f_i R_i`` at ``points (M, 3)``, touching only (point, perturbation) pairs whose point lies
    in the perturbation's bounding ball. Differentiable in ``P`` and ``points``; not transform-safe."""
    from scipy.spatial import cKDTree

    Pn = P.detach().cpu().double().numpy()
    radii = support_radii(Pn) * (1.0 + 1e-9) + 1e-12
    out = []
    for start in range(0, points.shape[0], SPARSE_CHUNK):
        pts = points[start:start + SPARSE_CHUNK]
        tree = cKDTree(pts.detach().cpu().double().numpy())
        ok = np.isfinite(radii)
        lists: list = [np.arange(len(pts))] * len(Pn)          # a singular A: every point
        if ok.any():
            found = tree.query_ball_point(Pn[ok, :3], radii[ok], return_sorted=False)
            for i, hits in zip(np.flatnonzero(ok), found):
                lists[i] = hits
        sizes = np.fromiter((len(v) for v in lists), dtype=np.int64, count=len(lists))
        acc = torch.zeros(pts.shape[0], dtype=points.dtype, device=points.device)
        if sizes.sum():
            pi = torch.as_tensor(np.concatenate([np.asarray(v, dtype=np.int64) for v in lists]), device=points.device)
            ki = torch.as_tensor(np.repeat(np.arange(len(Pn)), sizes), device=points.device)
            Pk = P[ki]
            acc = acc.index_add(0, pi, bump_values(Pk, pts[pi] - Pk[:, :3]))
        out.append(acc)
    return torch.cat(out)


def field(theta: torch.Tensor, points: torch.Tensor, n: int) -> torch.Tensor:
    """``F (...)`` at ``points (..., 3)`` for ``theta (10 + 10 n,)`` (module docstring); dtype and device
    follow ``points``. Large plain inputs use the exact sparse path."""
    theta = theta.to(points.dtype)
    q, P = theta[:N_BASE], theta[N_BASE:].reshape(n, N_PERT)
    base = quadric(q, points)
    if n == 0:
        return base
    if points.dim() == 2 and points.shape[0] * n > DENSE_BUDGET:
        if not (_is_transformed(points) or _is_transformed(theta)):
            return base + _sparse_bumps(P, points)
        rows = max(1, DENSE_BUDGET // n)
        return base + torch.cat([bumps(P, c) for c in torch.split(points, rows)])
    return base + bumps(P, points)


def quadric_matrix(q: np.ndarray) -> tuple[np.ndarray, np.ndarray, float]:
    """``(M (3, 3), b (3,), c)`` with ``B(p) = p^T M p + b . p + c``."""
    M = np.array([[q[0], q[3] / 2, q[4] / 2], [q[3] / 2, q[1], q[5] / 2], [q[4] / 2, q[5] / 2, q[2]]])
    return M, np.asarray(q[6:9], dtype=np.float64), float(q[9])


def upper(P: np.ndarray) -> np.ndarray:
    """Upper-triangular matrices ``(N, 3, 3)`` of perturbations ``P (N, 10)``."""
    A = np.zeros((len(P), 3, 3))
    A[:, 0, 0], A[:, 0, 1], A[:, 0, 2] = P[:, 3], P[:, 4], P[:, 5]
    A[:, 1, 1], A[:, 1, 2], A[:, 2, 2] = P[:, 6], P[:, 7], P[:, 8]
    return A


class PerturbField(ValuesField):
    """A perturbation field with stored values: ``sdf(theta, points)``, ``with_theta``, ``with_values``,
    ``bounds`` (the interface of :class:`ipm.sdf.nodes.Tree` used by fitting and the CLI)."""

    def _eval(self, theta: torch.Tensor, points: torch.Tensor) -> torch.Tensor:
        return field(theta, points, self.gen.n)

    def bounds(self) -> tuple[np.ndarray, np.ndarray]:
        """Box ``(lo (3,), hi (3,))``: the base ellipsoid's box (if the quadric is one) grown by the boxes
        of material-adding perturbations, padded by 2% and clipped to ``[-extent, extent]^3``; the
        whole domain if the base is not an ellipsoid."""
        th = self.theta().numpy()
        n, e = self.gen.n, self.gen.extent
        lo, hi = np.full(3, -e), np.full(3, e)
        M, b, c = quadric_matrix(th[:N_BASE])
        w = np.linalg.eigvalsh(M)
        if w.min() > 1e-9:
            m = -0.5 * np.linalg.solve(M, b)
            k = float(m @ M @ m - c)
            if k <= 0:
                lo, hi = np.full(3, np.inf), np.full(3, -np.inf)
            else:
                half = np.sqrt(k * np.diag(np.linalg.inv(M)))
                lo, hi = m - half, m + half
            P = th[N_BASE:].reshape(n, N_PERT)
            add = P[P[:, 9] < 0]
            if len(add):
                A = upper(add)
                ok = np.abs(np.linalg.det(A)) > 1e-12
                for Ai, ci in zip(A[ok], add[ok, :3]):
                    S = np.linalg.inv(Ai.T @ Ai)
                    h = np.sqrt(np.maximum(np.diag(S), 0))
                    lo, hi = np.minimum(lo, ci - h), np.maximum(hi, ci + h)
                if not ok.all():
                    lo, hi = np.full(3, -e), np.full(3, e)
            pad = 0.02 * max(float(np.max(hi - lo)), 1e-3) if np.all(hi >= lo) else 0.0
            lo, hi = np.maximum(lo - pad, -e), np.minimum(hi + pad, e)
        if np.any(hi <= lo):                    # empty: a small box, the mesher then finds nothing
            lo, hi = np.full(3, -0.1), np.full(3, 0.1)
        return lo, hi


def _load(path: str) -> PerturbGenerator:
    return PerturbGenerator.from_file(path)


@register_generator("perturb", from_file=_load)
class PerturbGenerator(Generator):
    """Base quadric + ``perturbations`` perturbation functions (module docstring).

    values: parameter values (missing ones take the defaults). The defaults: a sphere of radius 0.8
    with zero-amplitude perturbations of radius 0.4 centered on it along the axes (a start for ``ipm fit``).
    """

    kind = "sdf"
    description = "base quadric + C2 perturbation functions (Vyatkin et al.); marching cubes"

    def __init__(self, perturbations: int = 6, values: Mapping[str, float] | None = None, *,
                 extent: float = 1.5, name: str = "perturb"):
        if isinstance(perturbations, bool) or not isinstance(perturbations, (int, np.integer)) or perturbations < 0:
            raise InputError(f"perturbations: expected an integer >= 0, got {perturbations!r}")
        if not (isinstance(extent, (int, float)) and np.isfinite(extent) and extent > 0):
            raise InputError(f"extent: expected a positive number, got {extent!r}")
        self.name = name
        self.n = int(perturbations)
        self.extent = float(extent)
        self.presets = {}
        default = self._default_values()
        if values is not None:
            unknown = set(values) - set(default)
            if unknown:
                raise InputError(f"unknown parameter(s) {', '.join(sorted(unknown)[:5])}; expected "
                                 f"base.<{'|'.join(BASE)}> or p<i>.<{'|'.join(PERT)}> with i < {self.n}")
            default.update({k: float(v) for k, v in values.items()})
        self.spec = ParamSpec(tuple(self._param(k, v) for k, v in default.items()))
        self.tree = PerturbField(self, self.spec.defaults())

    def _default_values(self) -> dict[str, float]:
        r = 0.8
        base = [1 / (2 * r), 1 / (2 * r), 1 / (2 * r), 0, 0, 0, 0, 0, 0, -r / 2]
        dirs = np.vstack([np.eye(3), -np.eye(3)])
        P = []
        for i in range(self.n):
            c = dirs[i % 6] * r * (1.0 - 0.1 * (i // 6))
            P += [*c.tolist(), 2.5, 0.0, 0.0, 2.5, 0.0, 2.5, 0.0]
        return dict(zip(param_names(self.n), [float(v) for v in base + P]))

    @staticmethod
    def _param(name: str, value: float) -> Param:
        """Bounds wide enough for converted shapes in the normalized frame (grown to fit ``value``)."""
        key = name.split(".", 1)[1]
        if name.startswith("base."):
            lim, doc = 100.0, "base quadric coefficient"
        elif key in ("cx", "cy", "cz"):
            lim, doc = 4.0, "perturbation center"
        elif key == "f":
            lim, doc = 10.0, "perturbation amplitude (> 0 removes material)"
        else:
            lim, doc = 500.0, "perturbation shape (upper-triangular A; 1 / radius)"
        lim = max(lim, float(math.ceil(abs(value) * 1.5)))
        return Param(name, value, -lim, lim, "float", doc)

    # -- geometry ------------------------------------------------------------------------------
    def tree_for(self, discrete: Mapping[str, int] | None = None) -> PerturbField:
        """The field object (no discrete parameters: the number of perturbations is structure)."""
        return self.tree

    def sdf(self, theta: torch.Tensor, points: torch.Tensor, discrete: Mapping[str, int] | None = None):
        """``F (...)`` at ``points (..., 3)``, negative inside; differentiable in ``theta`` and points."""
        return field(theta, points, self.n)

    def check_meshing(self, values: Mapping[str, Value], resolution: int) -> None:
        """Marching cubes over the field's bounds: the grid must fit in memory (:func:`check_field_meshing`)."""
        check_field_meshing(self.tree, values, resolution)

    def to_mesh(self, values: Mapping[str, Value], *, resolution: int | None = None, lod=None) -> TriMesh:
        """Marching cubes of ``F`` on a full grid over :meth:`PerturbField.bounds` (``resolution`` samples
        along the longest side; float64 vertices, outward faces; empty if ``F`` has no zero crossing)."""
        from skimage.measure import marching_cubes

        from ipm.sdf.meshing import check_resolution, grid_shape

        fld = self.tree.with_values(values)
        lo, hi = fld.bounds()
        res = resolution or 128
        check_resolution(res, lo, hi)
        origin, h, shape = grid_shape(lo, hi, res)
        axes = [torch.as_tensor(origin[k] + h * np.arange(shape[k]), dtype=torch.float32) for k in range(3)]
        pts = torch.stack(torch.meshgrid(*axes, indexing="ij"), -1).reshape(-1, 3)
        with torch.no_grad():
            vol = field(fld.theta(torch.float32), pts, self.n).reshape(shape).numpy()
        if vol.min() >= 0 or vol.max() <= 0:
            return TriMesh(torch.zeros(0, 3, dtype=torch.float64), torch.zeros(0, 3, dtype=torch.int64))
        verts, faces, _, _ = marching_cubes(vol, 0.0, spacing=(h, h, h), gradient_direction="descent",
                                            allow_degenerate=False)
        return TriMesh(torch.from_numpy(verts.astype(np.float64) + origin), torch.from_numpy(faces.astype(np.int64)))

    # -- files ---------------------------------------------------------------------------------
    def to_json(self, values: Mapping[str, Value] | None = None, **extra) -> dict:
        """``{"generator": "perturb", "perturbations": N, "extent": E, "params": {...}, ...extra}``."""
        return {"generator": FORMAT, "perturbations": self.n, "extent": self.extent,
                "params": dict(self.spec.validate(values or {})), **extra}

    def metadata(self, values: Mapping[str, Value]) -> dict:
        """The whole file document (:meth:`to_json`), so exports can be loaded back as a generator."""
        return self.to_json(values)

    @staticmethod
    def from_json(data: Mapping) -> PerturbGenerator:
        """A generator from :meth:`to_json`'s document; ``ValueError`` says what is missing or wrong."""
        check_format(data, FORMAT, "perturb file")
        if "perturbations" not in data or not isinstance(data.get("params"), Mapping):
            raise InputError("perturb file: expected fields perturbations (a count) and params (an object)")
        try:
            n = int(data["perturbations"])
            kw = {"extent": float(data["extent"])} if "extent" in data else {}
        except (TypeError, ValueError):
            raise InputError("perturb file: expected numbers for perturbations and extent") from None
        return PerturbGenerator(n, dict(data["params"]), **kw)

    @staticmethod
    def from_file(path: str | Path) -> PerturbGenerator:
        """Load a file written by :meth:`to_json` (``ipm convert --to perturb``)."""
        from ipm.files import read_json

        data = read_json(path, "perturb file")
        return PerturbGenerator.from_json(data)
