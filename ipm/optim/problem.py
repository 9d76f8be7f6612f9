"""The problem a fit solves: a generator, a target and the search vector's layout
(:mod:`ipm.optim.encoding`), turned into one objective ``(x, discrete, need_grad[, phase]) -> (loss, grad,
extras)``.

The generator is seen through its shape adapter (:mod:`ipm.optim.shapes`: the only code that knows whether
it makes meshes or signed distances); the loss is the sum of the terms that apply to the target
(:mod:`ipm.optim.terms`), less those the phase leaves out (:class:`~ipm.optim.phases.Phase`). The
generator's output is first brought to a canonical frame (bounding-box center at the origin, longest side 2,
measured once on the starting shape), then posed; a mesh target's fit starts with the scale that gives the
starting shape the target's bounding sphere. One evaluation is one render of every view plus the loss (or,
for a mesh target, one loss).
"""

from __future__ import annotations

import dataclasses
from collections.abc import Mapping
from typing import TYPE_CHECKING

import torch

from ipm import losses as L
from ipm.errors import InputError
from ipm.losses import cues as C
from ipm.optim import encoding as E
from ipm.optim.phases import SEARCH, Phase
from ipm.optim.shapes import Pose, rot_y, shape_for
from ipm.optim.targets import MaskTarget, MeshTarget
from ipm.optim.terms import Evaluation, active_terms
from ipm.optim.terms.outside import OUTSIDE_WEIGHT, outside_share
from ipm.optim.terms.silhouette import centroids
from ipm.params import Param
from ipm.types import Camera, TriMesh

__all__ = ["OUTSIDE_WEIGHT", "Problem", "centroids", "outside_share", "rot_y"]

if TYPE_CHECKING:
    from ipm.optim.settings import FitSettings


def _narrowed(p: Param, rng) -> Param:
    """Discrete parameter ``p`` with its search range narrowed to ``rng = [lo, hi]`` (within its bounds)."""
    if rng is None:
        return p
    if len(rng) != 2 or not all(float(v).is_integer() for v in rng):
        raise InputError(f"ranges: {p.name}: expected [lo, hi] integers, got {rng}")
    lo, hi = int(rng[0]), int(rng[1])
    if not p.lo <= lo <= hi <= p.hi:
        raise InputError(f"ranges: {p.name}: expected {p.lo} <= lo <= hi <= {p.hi}, got [{lo}, {hi}]")
    return dataclasses.replace(p, lo=lo, hi=hi, default=min(max(p.default, lo), hi))


def _searched(gen, settings: FitSettings) -> list[Param]:
    """The discrete parameters the fit searches (none with ``discrete="none"``), their ranges narrowed to
    ``settings.ranges``, within the strategy's own limits."""
    searched = [_narrowed(p, settings.ranges.get(p.name)) for p in gen.spec.discrete if p.name not in settings.fix]
    unknown = sorted(set(settings.ranges) - {p.name for p in searched})
    if unknown:
        raise InputError(f"ranges: {', '.join(unknown)}: not a searched discrete parameter; expected one of "
                         f"{', '.join(p.name for p in searched) or 'none'}")
    if settings.discrete == "none":
        searched = []
    from ipm.optim.strategies import STRATEGIES

    strategy = STRATEGIES[settings.discrete]
    if getattr(strategy, "ranged_only", False) and settings.ranges:
        # a strategy that searches only the parameters given ranges (enumerate, when some are; it says
        # so when it runs): the others are held at the start's values, as if fixed
        searched = [p for p in searched if p.name in settings.ranges]
    pre_check = getattr(strategy, "check", None)  # a strategy's own limits
    if pre_check is not None and searched:
        pre_check(searched)
    return searched


def reframed(t: torch.Tensor, yaw, scale, frame: tuple, to: tuple) -> tuple[torch.Tensor, torch.Tensor]:
    """The translation and scale that place a shape measured in canonical frame ``to`` (center, longest side:
    :meth:`Problem.frame`) where ``(t, yaw, scale)`` places it measured in ``frame``. The world map is
    ``scale * (p - c) * 2 / size @ R^T + t``; written with ``to``'s center and size it keeps every point."""
    (c, size), (c2, size2) = frame, to
    return t + (scale * 2.0 / size) * (c2 - c) @ rot_y(yaw).T, scale * size2 / size


class Problem:
    """A generator, a target and the layout of the search vector (see the module docstring)."""

    def __init__(self, gen, target: MaskTarget | MeshTarget, settings: FitSettings, *, dtype=torch.float32,
                 reference: Mapping[str, int] | None = None):
        """``reference``: the counts that sizes declared per a count are held for (:meth:`carry`); default the
        start's. A fit from a learned proposal passes the proposal's, so that it is represented as it is."""
        settings.check()
        self.gen, self.target, self.s = gen, target, settings
        self.dtype = dtype
        self.shape = shape_for(gen, settings, dtype)
        self.device = target.masks.device if isinstance(target, MaskTarget) else target.mesh.verts.device
        self.start = gen.values(settings.preset, settings.fix)
        cont = [p.name for p in gen.spec.continuous]
        held = {p.name for p in gen.spec.continuous if p.held}
        free = (settings.free if settings.free is not None
                else [n for n in cont if n not in settings.fix and n not in held])
        unknown = [n for n in free if n not in cont]
        if unknown:
            raise InputError(f"free parameters: expected continuous parameters ({', '.join(cont)}), got "
                             f"{', '.join(unknown)}")
        self.free = [cont.index(n) for n in free]
        self.n = len(self.free)
        self.theta0, self.d0 = gen.split(self.start, torch.float64)
        # sizes per a discrete count (see carry), with their index in theta
        self._per = [(i, p) for i, p in enumerate(gen.spec.continuous)
                     if p.per is not None and p.per in self.d0 and i in self.free]
        self.lo, self.hi = gen.spec.lower(), gen.spec.upper()
        self.searched = _searched(gen, settings)
        self.d0 = self.clamp_discrete(self.d0)
        # the counts the search holds sizes per count for (carry): the start's, or the reference's where the fit
        # searches that count; the start's sizes are then held as they would be for those counts
        searched = {q.name for q in self.searched}
        ref = {k: int(v) for k, v in (reference or {}).items() if k in searched}
        self.ref = self.clamp_discrete({p.per: ref.get(p.per, self.d0[p.per]) for _, p in self._per})
        self.theta0 = self.carry(self.theta0, self.d0, inverse=True)
        if settings.subdivide is not None and not self.shape.has_faces:
            raise InputError(f"subdivision: applies to mesh generators; {gen.name} is an SDF generator")
        self.cam_fit = isinstance(target, MaskTarget) and settings.camera == "fit"
        self.layout = E.Layout(self.lo, self.hi, tuple(self.free), self.cam_fit)
        self.m = self.layout.m
        self.pose_mask = torch.ones(self.m, dtype=torch.float64)
        if not settings.pose:
            self.pose_mask[self.layout.pose] = 0
        if self.cam_fit:  # camera coordinates the target fixes (camera_triple) are not searched
            at = self.m - E.CAMERA_SIZE
            if target.ground_elevation is not None:
                self.pose_mask[at] = 0
            if target.known_intrinsics:
                self.pose_mask[at + 2] = 0
        # coarse to fine: detail parameters (per-section offsets, ...) stay at their start during the
        # search of a silhouette fit, which then explores fewer, better-determined dimensions; the
        # polish frees them. A mesh target determines them all: holding them there only lets the coarse
        # parameters bend to fit what the details should (the real mug scan: F-score at 0.02 of 0.72
        # with, 0.88 without)
        by_name = {p.name: p for p in gen.spec.continuous}
        c2f = settings.coarse_to_fine and isinstance(target, MaskTarget)
        detail = [i for i, j in enumerate(self.free) if c2f and by_name[cont[j]].detail]
        if len(detail) == self.n:
            detail = []
        self.coarse = [i for i in range(self.n) if i not in set(detail)]
        self.search_mask = self.pose_mask.clone()
        if isinstance(target, MaskTarget) and target.cues:
            self._check_cues(target)
        self.search_mask[detail] = 0
        # anchored parameters (Param.anchored) of a single-view fit without depth (which measures what one
        # silhouette confuses): charged their distance from the start
        # (and the parsimony rule's fits: ipm.optim.parsimony)
        self.one_view = isinstance(target, MaskTarget) and target.masks.shape[0] == 1 and target.depth is None
        self.anchored = [i for i, j in enumerate(self.free)
                         if self.one_view and settings.anchor > 0 and by_name[cont[j]].anchored]
        self._frames: dict = {}
        self._target_sphere: tuple | None = None
        self.c0, self.L0 = self.frame(self.d0)
        self.u_ref = self.encode_params(self.theta0)
        self.terms = active_terms(self)
        self.mask_loss = L.mask_loss(settings.loss, **dataclasses.asdict(settings.transport))

    def _check_cues(self, target: MaskTarget) -> None:
        """Cues need a mesh generator (depth, labels and normals come from its faces) whose parts include
        the named ones; the depth scale of each view is measured once."""
        if not self.shape.has_faces:
            raise InputError(f"{', '.join(target.cues)} targets: expected a mesh generator (ipm list generators), "
                             f"got the SDF generator {self.gen.name}; fit it to masks only")
        if target.parts is not None:
            start = self.carry(self.theta0, self.d0)
            known = tuple(self.gen.parts) or self.gen.mesh(start, self.d0, self.s.lod).group_names
            unknown = [n for n in target.part_names if n not in known]
            if unknown:
                raise InputError(f"part labels: {', '.join(unknown)}: not a part of {self.gen.name}; expected "
                                 f"names among {', '.join(known) or '(none: it has no parts)'}")
        self.depth_scales = ([C.depth_scale(d[m > 0.5]) for d, m in zip(target.depth, target.masks)]
                             if target.depth is not None else [])

    # -- the search vector (ipm.optim.encoding) ---------------------------------------------------
    def encode_params(self, theta: torch.Tensor) -> torch.Tensor:
        """``theta (N,)`` -> the free coordinates ``(n,)`` in [0, 1]."""
        return E.normalize(self.layout, theta)

    def x0(self, yaw: float = 0.0, scale: float = 1.0, t=(0.0, 0.0, 0.0), camera=None,
           theta: torch.Tensor | None = None) -> torch.Tensor:
        """``x (m,)`` of ``theta`` (default: the start) in the given pose (and camera)."""
        return E.encode(self.layout, self.theta0 if theta is None else theta, t=t, yaw=yaw, scale=scale,
                        camera=camera)

    def decode(self, x: torch.Tensor):
        """-> theta (n_all,), translation (3,), yaw (deg), scale, camera triple or None (all torch). theta is
        as the search holds it, for the reference counts (:attr:`ref`): see :meth:`carry`."""
        return E.decode(self.layout, x, self.theta0)

    def carry(self, theta: torch.Tensor, discrete: Mapping[str, int], inverse: bool = False) -> torch.Tensor:
        """The search's ``theta (N,)`` as the generator's for ``discrete`` values: a size declared ``per`` a
        count (:class:`~ipm.params.Param`; a storey's height per floor) is held by the search as it
        would be with the reference count (:attr:`ref`: the start's, or a learned proposal's), and scaled by
        ``reference count / count`` here (clamped to its bounds), so that a candidate with another count
        keeps the total (9 floors start as tall as the 7 they replace, and the part labels, not the outline,
        tell them apart). The search holds the size within its bounds, so only counts within their ratio
        (2.3 for a storey: 2.2 to 5 m) of the reference reach every size: 27 storeys of 3 m held for the
        default start's 5 are all 2.2 m high (the building's true values posed from one view: held-out IoU
        0.80 held for the start's counts, 0.89 for their own, results/proposal_ablation.md), and the other way
        round, with a reference of 9 storeys a 2-storey preset's come out at the 5 m bound. Sizes the fit does
        not move (fixed, held) are left as they are. ``inverse``: the other way, for encoding a theta of
        ``discrete``. Differentiable; the identity without such sizes."""
        d = {**self.d0, **discrete}
        out = theta
        for i, p in self._per:
            if d[p.per] == self.ref[p.per]:
                continue
            k = self.ref[p.per] / d[p.per]
            v = theta[i] * (1.0 / k if inverse else k)
            out = out.index_put((torch.tensor([i], device=theta.device),), v.clamp(p.lo, p.hi).reshape(1))
        return out

    def part_cost(self, discrete: Mapping[str, int]) -> float:
        """The description length of ``discrete`` (the starting values where absent): ``part_cost`` per part
        its values add (:attr:`ipm.params.Param.adds`), a constant of the continuous values."""
        if self.s.part_cost == 0:
            return 0.0
        d = {**self.d0, **discrete}
        return self.s.part_cost * float(sum(int(d[p.name]) for p in self.gen.spec.discrete if p.adds))

    def clamp_discrete(self, d: Mapping[str, int]) -> dict:
        """``d`` with the searched values moved into their (possibly narrowed) ranges."""
        out = dict(d)
        for p in self.searched:
            if p.name in out:
                out[p.name] = int(min(max(out[p.name], p.lo), p.hi))
        return out

    def values(self, x: torch.Tensor, discrete: Mapping[str, int]) -> dict:
        """The named parameter dict of ``x (m,)`` and ``discrete`` (the starting values where absent)."""
        theta = self.carry(self.decode(x.detach().double())[0], discrete)
        return E.from_vectors(self.gen.spec, theta, {**self.d0, **discrete})

    def repose(self, x: torch.Tensor, d_from: Mapping[str, int], d_to: Mapping[str, int]) -> torch.Tensor:
        """``x`` (m,) of a shape with discrete values ``d_from``, re-encoded for ``d_to`` so that what the two
        have in common stays where it is in the world. The canonical frame (:meth:`frame`) depends on the
        discrete values (a handle makes the shape wider), so the same pose coordinates alone would move
        and scale it."""
        x = x.detach().double()
        _, t, yaw, scale, _ = self.decode(x)
        t2, scale2 = reframed(t, yaw, scale, self.frame(d_from), self.frame(d_to))
        out = x.clone()
        out[self.n:self.n + 3] = E.encode_translation(t2)
        out[self.n + 4] = E.encode_log2_scale(torch.log2(scale2))
        return out.clamp(0, 1)

    def adopt(self, other: Problem, x: torch.Tensor, discrete: Mapping[str, int]) -> torch.Tensor:
        """``x (m,)`` of problem ``other`` (the same generator and free parameters; say a fit to more views) with
        ``discrete`` values, encoded for this problem: the same generator values and the same shape in the world.
        Sizes per count are held for each problem's own reference counts (:meth:`carry`) and the pose is relative to
        each one's canonical frame (:meth:`frame`), so ``x`` itself means another shape here."""
        if other.gen.name != self.gen.name or other.free != self.free or other.cam_fit != self.cam_fit:
            raise ValueError(f"adopt: expected a problem of {self.gen.name} with the same free parameters, got one of "
                             f"{other.gen.name}")
        x = x.detach().double()
        theta, t, yaw, scale, cam = other.decode(x)
        d = {**other.d0, **discrete}
        held = self.carry(other.carry(theta, d), d, inverse=True)
        t2, scale2 = reframed(t, yaw, scale, other.frame(d), self.frame(d))
        return E.encode(self.layout, held, t=[float(v) for v in t2], yaw=float(yaw), scale=float(scale2),
                        camera=None if cam is None else [float(v) for v in cam])

    def mesh_start(self, discrete: Mapping[str, int]) -> dict:
        """``{"scale", "t"}`` that put the starting shape's bounding sphere (about its box center) on the
        mesh target's; empty for silhouettes, whose pose grid sets them from the masks."""
        if not isinstance(self.target, MeshTarget):
            return {}
        if self._target_sphere is None:
            v = self.target.mesh.verts.detach().double()
            c = 0.5 * (v.amin(0) + v.amax(0))
            self._target_sphere = (c, float(torch.linalg.vector_norm(v - c, dim=1).max()))
        c_t, r_t = self._target_sphere
        d = {**self.d0, **discrete}
        c0, L0 = self.frame(d)
        v = self.shape.vertices(self.carry(self.theta0, d), d)
        r0 = float(torch.linalg.vector_norm(v - c0, dim=1).max()) * 2.0 / L0
        return {"scale": r_t / max(r0, 1e-12), "t": tuple(float(x) for x in c_t)}

    def pose_json(self, x: torch.Tensor, discrete: Mapping[str, int] | None = None, symmetry: bool = False,
                  mesh: TriMesh | None = None) -> dict:
        """The pose as JSON; with ``symmetry``, also the turns that map the posed shape onto itself
        (:func:`ipm.optim.symmetry.yaw_symmetry`; ``mesh``: the posed mesh if already made), whether the yaw
        is free (a body of revolution) and the equivalent poses (``equivalent``: one per turn; a
        revolution's every 45 degrees)."""
        _, t, yaw, scale, _ = self.decode(x.detach().double())
        cam = self.camera_triple(x.detach().double())
        c0, L0 = self.frame(discrete or {})
        out = {"translation": [float(v) for v in t], "yaw_deg": float(yaw), "scale": float(scale),
               "canonical_center": [float(v) for v in c0], "canonical_size": float(L0)}
        if cam is not None:
            out["camera"] = {"elevation_deg": float(cam[0]), "distance": float(cam[1]), "fov_deg": float(cam[2])}
        if symmetry:
            from ipm.optim.symmetry import equivalent_poses, yaw_symmetry

            if mesh is None:
                with torch.no_grad():
                    mesh = self.mesh_world(x.detach().double(), dict(discrete or {}))
            m = mesh
            sym = yaw_symmetry(m.verts.double().cpu().numpy(), m.faces.cpu().numpy())
            out["symmetry"] = sym.to_json()
            out["yaw_free"] = sym.kind == "revolution"
            out["equivalent"] = equivalent_poses(sym, float(yaw), t.tolist())
        return out

    # -- geometry --------------------------------------------------------------------------------
    def frame(self, discrete: Mapping[str, int]) -> tuple[torch.Tensor, float]:
        """Bounding-box center (3,) and longest side of the shape with these discrete values at the
        starting continuous values. It depends on the discrete values only, so that a search
        that changes a count (floors, boxes) starts that candidate at the right size, and replays stay
        exact."""
        d = {**self.d0, **discrete}
        key = tuple(sorted(d.items()))
        if key not in self._frames:
            v = self.shape.vertices(self.carry(self.theta0, d), d)
            if len(v) == 0:
                raise InputError(f"{self.gen.name}: expected a shape at the starting parameters, got an empty "
                                 f"one for {d}")
            lo, hi = v.min(0).values, v.max(0).values
            # the longest side, not the bounding sphere: a part that widens the box sideways (a handle) then
            # leaves the body's size alone when a search switches it on (with the sphere's diameter, enumerate
            # lost the tall mug's handle: tests/test_fit_generators.py)
            self._frames[key] = (0.5 * (lo + hi), float((hi - lo).max()))
        return self._frames[key]

    def posed(self, x: torch.Tensor, discrete: Mapping[str, int]) -> tuple[torch.Tensor, dict, Pose]:
        """``(theta (N,), discrete values, pose)`` of ``x (m,)``: the generator's values (counts carried,
        :meth:`carry`), the discrete values with the starting ones where absent, the canonical frame's pose."""
        theta, t, yaw, scale, _ = self.decode(x)
        d = {**self.d0, **discrete}
        c0, size = self.frame(d)
        return self.carry(theta, d), d, Pose(t, yaw, scale, c0, size)

    def mesh_world(self, x: torch.Tensor, discrete: dict, pose_grad: bool = True) -> TriMesh:
        """The posed mesh (world frame of the target); differentiable in ``x`` where the shape is (in its
        generator coordinates only, without ``pose_grad``)."""
        if not pose_grad:
            x = torch.cat([x[: self.n], x[self.n:].detach()])
        theta, d, pose = self.posed(x, discrete)
        return self.shape.world_mesh(theta, d, pose)

    def camera_triple(self, x: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor] | None:
        """The fitted camera's (elevation, distance, FOV) as rendered (None without a camera fit): the
        FOV of known intrinsics and the elevation of a known ground (:class:`MaskTarget`) replace the
        coordinates of ``x``, which are then unused (zero gradient)."""
        if not self.cam_fit:
            return None
        _, _, _, _, (elev, dist, fov) = self.decode(x)
        c0 = self.target.cameras[0]
        if self.target.known_intrinsics:
            fov = c0.fov_deg.to(dtype=elev.dtype, device=elev.device)
        if self.target.ground_elevation is not None:
            elev = torch.as_tensor(self.target.ground_elevation, dtype=elev.dtype, device=elev.device)
        return elev, dist, fov

    def cameras(self, x: torch.Tensor) -> list[Camera]:
        cams = self.target.cameras
        if not self.cam_fit:
            return cams
        from ipm.render.camera import orbit_camera

        elev, dist, fov = self.camera_triple(x)
        c0 = cams[0]
        return [orbit_camera(torch.zeros((), dtype=elev.dtype), elev, dist, fov_deg=fov, width=c0.width,
                             height=c0.height, cx=c0.cx, cy=c0.cy)]

    # -- the objective ---------------------------------------------------------------------------
    def render_soft(self, x: torch.Tensor, discrete: dict, mesh: TriMesh | None = None,
                    phase: Phase = SEARCH) -> torch.Tensor:
        """Soft silhouettes ``(K, H, W)`` of the posed shape in every view at ``phase``'s blur (``mesh``: the
        posed mesh, if already made)."""
        theta, d, pose = self.posed(x, discrete)
        return self.shape.silhouettes(theta, d, pose, self.cameras(x), phase.sigma, mesh)

    def objective(self, x: torch.Tensor, discrete: dict, need_grad: bool, phase: Phase = SEARCH):
        """``(loss (0-dim), gradient (m,) or None, extras)`` at ``x (m,)``: the sum of :attr:`terms` in their
        order, less those ``phase`` leaves out, at ``phase``'s blur; the gradient is zero on the pose (and
        camera) coordinates that are not searched."""
        x = x.detach().clone().requires_grad_(need_grad)
        with torch.set_grad_enabled(need_grad):
            ev = Evaluation(self, x, discrete, phase, need_grad)
            loss = None
            for term in self.terms:
                if term.name in phase.without:
                    continue
                value = term(ev)
                loss = value if loss is None else loss + value
            grad = None
            if need_grad:
                (g,) = torch.autograd.grad(loss, x, allow_unused=True)
                grad = torch.zeros_like(x) if g is None else g * self.pose_mask
        return loss.detach(), grad, ev.extras
