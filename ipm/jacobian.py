"""Jacobians of generator outputs with respect to their parameters (torch.func), and a float64
finite-difference check.

SDF generators: ``f(theta (n,), points (N, 3)) -> (N,)``; the Jacobian is ``(N, n + 3)``: one row per
point, the derivatives with respect to every continuous parameter, then to the point's x, y, z.
Every output depends on its own point only, which the reverse mode exploits: ``vmap`` of a per-point
gradient computes all N rows in one batched backward pass, however large n is. The forward mode
pushes n + 3 tangents through one batched evaluation.

Mesh generators: ``f(theta (n,)) -> verts (V, 3)``; the Jacobian is ``(3V, n)`` (rows x0, y0, z0, x1, ...).
Forward mode is the natural choice (3V outputs, n inputs).

Size: a Jacobian has at most :data:`MAX_ENTRIES` entries (rows x columns), refused by
:func:`check_entries` before any work (:func:`sdf_jacobian` checks its own; callers that know a mesh's
vertex count, subdivided or not, check it before building the mesh's Jacobian).
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from typing import Literal

import torch
from torch.func import grad, jacfwd, jacrev, jvp, vmap

from ipm.errors import InputError

Mode = Literal["auto", "fwd", "rev"]
MODES = ("auto", "fwd", "rev")

SdfFn = Callable[[torch.Tensor, torch.Tensor], torch.Tensor]
MeshFn = Callable[[torch.Tensor], torch.Tensor]

# Below this many columns the forward mode's batched tangents are cheaper than per-point gradients
# (measured by `make bench`, results/perf/jacobian.md).
FWD_MAX_COLUMNS = 4


# The most entries a Jacobian may have: 2**28 (2 GiB at float64). Here the Jacobian of a subdivided dishes
# mesh of 130 million entries took 10 s and 2.8 GB; at the limit about 20 s and 6 GB, and a check (central
# differences, float64) holds a few more arrays of the same size: within a 24 GB machine.
MAX_ENTRIES = 2**28


def check_entries(rows: int, cols: int, what: str = "Jacobian", hint: str = "") -> None:
    """Refuse (:class:`InputError`, before any work) a Jacobian of ``rows x cols`` entries beyond
    :data:`MAX_ENTRIES`; ``what`` names it, ``hint`` says how to shrink it."""
    if rows * cols > MAX_ENTRIES:
        raise InputError(f"{what}: {rows:,} rows x {cols:,} columns are {rows * cols:,} entries; expected at most "
                         f"{MAX_ENTRIES:,} entries (the limit, 2 GiB at float64){'; ' + hint if hint else ''}")


def _check_mode(mode: str) -> None:
    if mode not in MODES:
        raise InputError(f"mode: expected one of {', '.join(MODES)}, got {mode!r}")


def sdf_jacobian(f: SdfFn, theta: torch.Tensor, points: torch.Tensor, mode: Mode = "auto",
                 chunk: int = 65536) -> torch.Tensor:
    """Jacobian ``(N, n + 3)`` of an SDF with respect to ``theta: (n,)`` and ``points: (N, 3)``.

    Points are processed ``chunk`` at a time to bound memory. dtype follows ``points``. More than
    :data:`MAX_ENTRIES` entries are refused before any work.
    """
    _check_mode(mode)
    if points.ndim != 2 or points.shape[-1] != 3:
        raise InputError(f"points: expected (N, 3), got {tuple(points.shape)}")
    theta = theta.to(points.dtype)
    n = theta.shape[0]
    check_entries(points.shape[0], n + 3, "SDF Jacobian", f"at most {MAX_ENTRIES // (n + 3):,} points here")
    if mode == "auto":
        mode = "fwd" if n + 3 <= FWD_MAX_COLUMNS else "rev"
    rows = _sdf_jac_fwd if mode == "fwd" else _sdf_jac_rev
    return torch.cat([rows(f, theta, points[i:i + chunk]) for i in range(0, len(points), chunk)])


def _sdf_jac_rev(f: SdfFn, theta: torch.Tensor, pts: torch.Tensor) -> torch.Tensor:
    def one(th, p):
        return f(th, p)

    g_theta, g_p = vmap(grad(one, argnums=(0, 1)), in_dims=(None, 0))(theta, pts)
    return torch.cat([g_theta, g_p], 1)


def _sdf_jac_fwd(f: SdfFn, theta: torch.Tensor, pts: torch.Tensor) -> torch.Tensor:
    n, N = theta.shape[0], pts.shape[0]
    k = n + 3
    eye = torch.eye(k, dtype=pts.dtype, device=pts.device)
    t_theta = eye[:, :n]                                    # (k, n)
    t_pts = eye[:, n:][:, None, :].expand(k, N, 3)          # (k, N, 3): same tangent for every point

    def push(tt, tp):
        return jvp(f, (theta, pts), (tt, tp))[1]

    # .to(): tangents can come out float64 for float32 inputs (see ipm.sdf._math.like)
    return vmap(push)(t_theta, t_pts).T.to(pts.dtype).contiguous()        # (N, k)


def mesh_jacobian(f: MeshFn, theta: torch.Tensor, mode: Mode = "auto") -> torch.Tensor:
    """Jacobian ``(3V, n)`` of vertex positions ``f(theta) -> (V, 3)``."""
    _check_mode(mode)

    def flat(th):
        return f(th).reshape(-1)

    if mode == "rev":
        return jacrev(flat)(theta)
    return jacfwd(flat)(theta)


@dataclass(frozen=True)
class JacobianCheck:
    """Result of a finite-difference check: ``max_rel_error`` is max |J - J_fd| / max(|J_fd|, 1)."""

    max_rel_error: float
    max_abs_error: float
    worst: tuple[int, int]
    step: float

    def ok(self, tol: float = 1e-6) -> bool:
        """True when the largest relative error is at most ``tol``."""
        return self.max_rel_error <= tol


def _compare(J: torch.Tensor, J_fd: torch.Tensor, step: float) -> JacobianCheck:
    diff = (J.double() - J_fd).abs()
    rel = diff / J_fd.abs().clamp(min=1.0)
    flat = int(rel.argmax()) if rel.numel() else 0
    worst = (flat // rel.shape[1], flat % rel.shape[1]) if rel.numel() else (0, 0)
    return JacobianCheck(float(rel.max()) if rel.numel() else 0.0,
                         float(diff.max()) if diff.numel() else 0.0, worst, step)


@torch.no_grad()
def sdf_fd_jacobian(f: SdfFn, theta: torch.Tensor, points: torch.Tensor, step: float = 1e-6) -> torch.Tensor:
    """Central differences in float64, ``(N, n + 3)`` (2(n + 3) evaluations)."""
    theta, points = theta.double(), points.double()
    cols = []
    for j in range(theta.shape[0]):
        e = torch.zeros_like(theta)
        e[j] = step
        cols.append((f(theta + e, points) - f(theta - e, points)) / (2 * step))
    for k in range(3):
        e = torch.zeros(3, dtype=torch.float64, device=points.device)
        e[k] = step
        cols.append((f(theta, points + e) - f(theta, points - e)) / (2 * step))
    return torch.stack(cols, 1)


@torch.no_grad()
def mesh_fd_jacobian(f: MeshFn, theta: torch.Tensor, step: float = 1e-6) -> torch.Tensor:
    """Central differences in float64, ``(3V, n)`` (2n evaluations)."""
    theta = theta.double()
    cols = []
    for j in range(theta.shape[0]):
        e = torch.zeros_like(theta)
        e[j] = step
        cols.append((f(theta + e).reshape(-1) - f(theta - e).reshape(-1)) / (2 * step))
    return torch.stack(cols, 1)


def check_sdf_jacobian(f: SdfFn, theta: torch.Tensor, points: torch.Tensor, J: torch.Tensor | None = None,
                       mode: Mode = "auto", step: float = 1e-6) -> JacobianCheck:
    """Compare the (float64) Jacobian with central differences."""
    theta, points = theta.double(), points.double()
    if J is None:
        J = sdf_jacobian(f, theta, points, mode)
    return _compare(J, sdf_fd_jacobian(f, theta, points, step), step)


def check_mesh_jacobian(f: MeshFn, theta: torch.Tensor, J: torch.Tensor | None = None,
                        mode: Mode = "auto", step: float = 1e-6) -> JacobianCheck:
    """Compare the vertex Jacobian ``(3V, n)`` (computed in float64 when not given) with central differences."""
    theta = theta.double()
    if J is None:
        J = mesh_jacobian(f, theta, mode)
    return _compare(J, mesh_fd_jacobian(f, theta, step), step)


# -- the Jacobian of a generator's output (ipm jacobian) ----------------------------------------------------

@dataclass
class OutputJacobian:
    """The Jacobian of a generator's output and what it is of: ``J`` (rows, columns) in the generator's dtype;
    ``names`` of the columns (the continuous parameters, then ``p.x p.y p.z`` for a field); ``arrays`` (what
    ``ipm jacobian`` writes beside it: ``points`` and ``sdf`` for a field, ``verts`` and ``faces`` for a mesh);
    ``info`` (kind, shape, method, subdivision); ``check``: the comparison with float64 central differences
    where asked."""

    J: torch.Tensor
    names: list[str]
    arrays: dict
    info: dict
    check: JacobianCheck | None = None


def _refuse_non_finite(arrays: dict, dtype: torch.dtype, where: str) -> None:
    """A result with NaN or infinite entries (float32 overflow, points far away) is bad input, not an output."""
    for name, a in arrays.items():
        bad = int((~torch.isfinite(a)).sum())
        if bad:
            raise InputError(f"{where}: expected a finite Jacobian, got {bad:,} NaN or infinite entries in {name} "
                             f"with dtype {str(dtype).removeprefix('torch.')}; use float64, or points nearer the "
                             "shape")


def subdivided_vertices(faces, n_verts: int, levels: int) -> int:
    """The vertices after ``levels`` levels of a linear scheme (loop, midpoint), counted, not built: each level
    adds one vertex per edge, E' = 2E + 3F, F' = 4F."""
    import numpy as np

    F = np.asarray(faces, dtype=np.int64).reshape(-1, 3)
    edges = np.sort(np.concatenate([F[:, [0, 1]], F[:, [1, 2]], F[:, [2, 0]]]), axis=1)
    v, e, f = n_verts, len(np.unique(edges, axis=0)), len(F)
    for _ in range(levels):
        v, e, f = v + e, 2 * e + 3 * f, 4 * f
    return v


def _field_output(g, theta, discrete, *, mode, points, n_points, rng, check, **_) -> OutputJacobian:
    """A field generator's distances at points ``(N, 3)`` (given, or ``n_points`` drawn by ``rng`` in the padded
    bounds): ``(N, n + 3)`` with respect to the parameters and the point."""
    tree = g.tree_for(discrete)
    names = [p.name for p in g.spec.continuous]
    cols = len(names) + 3
    n_rows = len(points) if points is not None else n_points
    check_entries(n_rows, cols, f"the Jacobian of {n_rows:,} points", f"at most {MAX_ENTRIES // cols:,} points here")
    if points is None:
        lo, hi = tree.with_theta(theta).bounds()
        pad = 0.1 * (hi - lo).max()
        points = torch.as_tensor(rng.uniform(lo - pad, hi + pad, size=(n_rows, 3)), dtype=theta.dtype,
                                 device=theta.device)

    def f(th, p):
        return tree.sdf(th, p)

    J = sdf_jacobian(f, theta, points, mode)
    at = f(theta, points).detach()
    _refuse_non_finite({"J": J, "sdf": at}, theta.dtype, f"{g.name} at {n_rows:,} points")
    chk = check_sdf_jacobian(f, theta, points[:2000], mode=mode) if check else None
    return OutputJacobian(J, names + ["p.x", "p.y", "p.z"], {"points": points, "sdf": at},
                          {"kind": "sdf", "shape": list(J.shape)}, chk)


def _mesh_output(g, theta, discrete, *, mode, lod, scheme, levels, check, **_) -> OutputJacobian:
    """A mesh generator's vertices: ``(3V, n)``, by the generator's own structured forward mode where it has one
    (``mode="auto"``), else by torch.func; with a linear subdivision ``scheme`` (its ``operator``), the
    subdivided mesh's ``S J`` (S fixed by the faces)."""
    names = [p.name for p in g.spec.continuous]

    def f(th):
        return g.mesh(th, discrete, lod).verts

    own = getattr(g, "jacobian", None)
    structured = mode == "auto" and own is not None
    if structured:  # the generator's closed-form rings and 3x3 blocks: the same values
        def jac(th):
            return own(th, discrete, lod)
    else:
        def jac(th):
            return mesh_jacobian(f, th, mode)

    mesh = g.mesh(theta, discrete, lod)
    faces = mesh.faces.cpu().numpy()
    if scheme is not None:
        rows = 3 * subdivided_vertices(faces, mesh.n_verts, levels)
        check_entries(rows, len(names), f"--subdivide {scheme.name} --levels {levels}",
                      f"3 x {rows // 3:,} vertices after {levels} level(s) x {len(names)} parameters; use fewer "
                      "--levels")
        op, faces = scheme.operator(faces, mesh.n_verts, levels)
        coarse_f, coarse_jac = f, jac

        def f(th):
            return op(coarse_f(th))

        def jac(th):
            J0 = coarse_jac(th)
            return op(J0.reshape(J0.shape[0] // 3, -1)).reshape(-1, J0.shape[1])
    else:
        check_entries(3 * mesh.n_verts, len(names), g.name, "use a lower --lod")
    verts = f(theta).detach() if scheme is not None else mesh.verts.detach()
    J = jac(theta)
    _refuse_non_finite({"J": J, "vertices": verts}, theta.dtype, f"{g.name} at these parameters")
    info = {"kind": "mesh", "shape": list(J.shape), "method": "structured" if structured else mode}
    if scheme is not None:
        info["subdivided"] = f"{scheme.name} x{levels}"
    chk = check_mesh_jacobian(f, theta, jac(theta.double())) if check else None
    return OutputJacobian(J, names, {"verts": verts, "faces": faces}, info, chk)


# the Jacobian of each kind of generator's output (``Generator.kind``): the one place that tells them apart;
# ``takes_points``: its rows are points given or drawn (a field), not the generator's own vertices (a mesh)
_field_output.takes_points, _mesh_output.takes_points = True, False
OUTPUTS = {"sdf": _field_output, "mesh": _mesh_output}


def output_jacobian(g, values, *, dtype: torch.dtype = torch.float64, device=None, mode: Mode = "auto", lod=None,
                    points: torch.Tensor | None = None, n_points: int = 10_000, seed: int = 0, scheme=None,
                    levels: int = 1, check: bool = False) -> OutputJacobian:
    """The Jacobian of generator ``g``'s output at ``values`` (a validated parameter dict): a field's distances at
    ``points (N, 3)`` or at ``n_points`` points drawn with ``seed``, ``(N, n + 3)``; a mesh's vertices ``(3V, n)``
    at ``lod``, subdivided ``levels`` times by the linear ``scheme`` where given (:mod:`ipm.subdiv`). Refused
    (:class:`InputError`) before any work beyond :data:`MAX_ENTRIES` entries, and after it where an entry is
    not finite."""
    import numpy as np

    _check_mode(mode)
    theta, discrete = g.split(values, dtype, device)
    return OUTPUTS[g.kind](g, theta, discrete, mode=mode, lod=lod, points=points, n_points=n_points,
                           rng=np.random.default_rng(seed), scheme=scheme, levels=levels, check=check)
