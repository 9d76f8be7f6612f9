"""The problem a fit solves: a generator, a target and the search vector's layout
(:mod:`ipm.optim.encoding`), turned into one objective ``(x, discrete, need_grad) -> (loss, grad, extras)``.

The generator's output is first brought to a canonical frame (bounding-box center at the origin, longest
side 2, measured once on the starting shape), then posed; a mesh target's fit starts with the scale that
gives the starting shape the target's bounding sphere. One evaluation is one render of every view plus
the loss (or, for a mesh target, one loss).
"""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Mapping
from typing import TYPE_CHECKING

import numpy as np
import torch

from ipm import losses as L
from ipm.errors import InputError
from ipm.losses import cues as C
from ipm.optim import encoding as E
from ipm.optim.targets import MaskTarget, MeshTarget
from ipm.params import Param
from ipm.types import Camera, TriMesh

# soft-rasterizer blur (px^2) of the part masks compared with part labels (Problem._soft_parts)
PARTS_SIGMA = 0.1

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


def centroids(masks: torch.Tensor) -> list[list[float]]:
    """Pixel centroids (x, y) of soft masks ``(K, H, W)`` (pixel centers at +0.5, row 0 at the top)."""
    K, H, W = masks.shape
    ys = torch.arange(H, dtype=masks.dtype, device=masks.device) + 0.5
    xs = torch.arange(W, dtype=masks.dtype, device=masks.device) + 0.5
    a = masks.sum((-2, -1)).clamp(min=1e-9)
    cx = (masks.sum(-2) * xs).sum(-1) / a
    cy = (masks.sum(-1) * ys).sum(-1) / a
    return [[round(float(x), 4), round(float(y), 4)] for x, y in zip(cx, cy)]


# weight of outside_share in a photo fit: 1 changed the ClearGrasp mug fit from photo IoU 0.964 to 0.919
# (its starting poses, partly outside the crop, ranked differently); 0.25 keeps it (0.966) and still holds
# the tumbler inside its crop (photo IoU 0.17-0.42 without, 0.962 with)
OUTSIDE_WEIGHT = 0.25


def outside_share(verts: torch.Tensor, cams: list[Camera]) -> torch.Tensor:
    """0-dim: how far the vertices ``(V, 3)`` project outside the images of ``cams``, in image heights,
    averaged over vertices and views (0 when all are inside). The silhouette loss does not see what falls
    outside a view; where that is known to be background (a photo's crop around its object) this charges
    it, and its gradient pulls the geometry back."""
    from ipm.render.camera import project

    out = []
    for c in cams:
        xy, _ = project(verts, c.to(dtype=verts.dtype, device=verts.device))
        x, y = xy[:, 0], xy[:, 1]
        d = (torch.relu(-x) + torch.relu(x - c.width) + torch.relu(-y) + torch.relu(y - c.height)) / c.height
        out.append(d.mean())
    return torch.stack(out).mean()


def rot_y(yaw_deg: torch.Tensor) -> torch.Tensor:
    """Rotation ``(3, 3)`` about +y by ``yaw_deg`` degrees (0-dim tensor), differentiable."""
    a = yaw_deg * (math.pi / 180.0)
    c, s = torch.cos(a), torch.sin(a)
    z, o = torch.zeros_like(c), torch.ones_like(c)
    return torch.stack([torch.stack([c, z, s]), torch.stack([z, o, z]), torch.stack([-s, z, c])])


class Problem:
    """A generator, a target and the layout of the search vector (see the module docstring)."""

    def __init__(self, gen, target: MaskTarget | MeshTarget, settings: FitSettings, *, dtype=torch.float32):
        settings.check()
        self.gen, self.target, self.s = gen, target, settings
        # the blur of the soft silhouettes relative to ``settings.sigma``; the polish lowers it, since
        # with a wide blur the 0.5 level of a soft silhouette lies outside the hard one (thin parts
        # such as handles come out too thin against hard masks)
        self.sigma_factor = 1.0
        # False while the outline is placed before the search (run_fit): part labels then count nothing
        self.use_parts = True
        self.dtype = dtype
        self.mask_loss = L.mask_loss(settings.loss, **dataclasses.asdict(settings.transport))
        self.device = target.masks.device if isinstance(target, MaskTarget) else target.mesh.verts.device
        self.start = gen.values(settings.preset, settings.fix)
        cont = [p.name for p in gen.spec.continuous]
        free = settings.free if settings.free is not None else [n for n in cont if n not in settings.fix]
        unknown = [n for n in free if n not in cont]
        if unknown:
            raise InputError(f"free parameters: expected continuous parameters ({', '.join(cont)}), got "
                             f"{', '.join(unknown)}")
        self.free = [cont.index(n) for n in free]
        self.n = len(self.free)
        self.theta0, self.d0 = gen.split(self.start, torch.float64)
        # sizes per a discrete count (see carry), with their index in theta
        self._per = [(i, p) for i, p in enumerate(gen.spec.continuous)
                     if p.per is not None and p.per in self.d0]
        self.lo, self.hi = gen.spec.lower(), gen.spec.upper()
        self.searched = [_narrowed(p, settings.ranges.get(p.name)) for p in gen.spec.discrete
                         if p.name not in settings.fix]
        unknown = sorted(set(settings.ranges) - {p.name for p in self.searched})
        if unknown:
            raise InputError(f"ranges: {', '.join(unknown)}: not a searched discrete parameter; expected one of "
                             f"{', '.join(p.name for p in self.searched) or 'none'}")
        if settings.discrete == "none":
            self.searched = []
        from ipm.optim.strategies import STRATEGIES

        strategy = STRATEGIES[settings.discrete]
        if getattr(strategy, "ranged_only", False) and settings.ranges:
            # a strategy that searches only the parameters given ranges (enumerate, when some are; it says
            # so when it runs): the others are held at the start's values, as if fixed
            self.searched = [p for p in self.searched if p.name in settings.ranges]
        pre_check = getattr(strategy, "check", None)  # a strategy's own limits
        if pre_check is not None and self.searched:
            pre_check(self.searched)
        self.d0 = self.clamp_discrete(self.d0)
        if settings.subdivide is not None and gen.kind != "mesh":
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
        one_view = isinstance(target, MaskTarget) and target.masks.shape[0] == 1 and target.depth is None
        self.anchored = [i for i, j in enumerate(self.free)
                         if one_view and settings.anchor > 0 and by_name[cont[j]].anchored]
        self._frames: dict = {}
        self._target_sphere: tuple | None = None
        self.c0, self.L0 = self.frame(self.d0)
        self.u_ref = self.encode_params(self.theta0)
        if isinstance(target, MeshTarget):
            gen_t = torch.Generator().manual_seed(settings.seed)
            tv, tf = target.mesh.verts.to(dtype), target.mesh.faces
            self.target_pts = L.SurfaceSampler.draw(tv, tf, target.samples, gen_t).points(tv)
            self._samplers: dict = {}
            if gen.kind == "sdf":
                from ipm.metrics import inside

                rng = np.random.default_rng(settings.seed)
                vol = rng.uniform(-1.1, 1.1, size=(target.samples, 3))
                V, F = tv.detach().double().numpy(), tf.numpy()
                self.vol_pts = torch.as_tensor(vol, dtype=dtype)
                self.vol_inside = torch.as_tensor(inside(vol, V, F))

    def _check_cues(self, target: MaskTarget) -> None:
        """Cues need a mesh generator (depth, labels and normals come from its faces) whose parts include
        the named ones; the depth scale of each view is measured once."""
        if self.gen.kind != "mesh":
            raise InputError(f"{', '.join(target.cues)} targets: expected a mesh generator (ipm list generators), "
                             f"got the SDF generator {self.gen.name}; fit it to masks only")
        if target.parts is not None:
            known = tuple(self.gen.parts) or self.gen.mesh(self.theta0, self.d0, self.s.lod).group_names
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
        as the search holds it, for the starting discrete values: see :meth:`carry`."""
        return E.decode(self.layout, x, self.theta0)

    def carry(self, theta: torch.Tensor, discrete: Mapping[str, int], inverse: bool = False) -> torch.Tensor:
        """The search's ``theta (N,)`` as the generator's for ``discrete`` values: a size declared ``per`` a
        count (:class:`~ipm.params.Param`; a storey's height per floor) is held by the search as it
        would be with the starting count, and scaled by ``start count / count`` here (clamped to its
        bounds), so that a candidate with another count keeps the total (9 floors start as tall as the
        7 they replace, and the part labels, not the outline, tell them apart). ``inverse``: the other
        way, for encoding a theta of ``discrete``. Differentiable; the identity without such sizes."""
        d = {**self.d0, **discrete}
        out = theta
        for i, p in self._per:
            if d[p.per] == self.d0[p.per]:
                continue
            k = self.d0[p.per] / d[p.per]
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
        c, size = self.frame(d_from)
        c2, size2 = self.frame(d_to)
        # _to_world maps p to scale * (p - c) * 2 / size @ R^T + t: the same map with (c2, size2)
        t2 = t + (scale * 2.0 / size) * (c2 - c) @ rot_y(yaw).T
        out = x.clone()
        out[self.n:self.n + 3] = E.encode_translation(t2)
        out[self.n + 4] = E.encode_log2_scale(torch.log2(scale * size2 / size))
        return out.clamp(0, 1)

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
        th = self.carry(self.theta0, d)
        v = (self.gen.mesh(th, d, self.s.lod).verts.detach().double() if self.gen.kind == "mesh" else
             self.gen.to_mesh(self.gen.spec.from_vector(th, d), resolution=48).verts.double())
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
            theta = self.carry(self.theta0, d)
            if self.gen.kind == "mesh":
                v = self.gen.mesh(theta, d, self.s.lod).verts.detach().double()
            else:
                v = self.gen.to_mesh(self.gen.spec.from_vector(theta, d), resolution=48).verts.double()
            if len(v) == 0:
                raise InputError(f"{self.gen.name}: expected a shape at the starting parameters, got an empty "
                                 f"one for {d}")
            lo, hi = v.min(0).values, v.max(0).values
            # the longest side, not the bounding sphere: a part that widens the box sideways (a handle) then
            # leaves the body's size alone when a search switches it on (with the sphere's diameter, enumerate
            # lost the tall mug's handle: tests/test_fit_generators.py)
            self._frames[key] = (0.5 * (lo + hi), float((hi - lo).max()))
        return self._frames[key]

    def _to_world(self, p: torch.Tensor, t, yaw, scale, discrete: Mapping[str, int]) -> torch.Tensor:
        c0, L0 = self.frame(discrete)
        R = rot_y(yaw).to(p.dtype)
        return scale.to(p.dtype) * ((p - c0.to(p.dtype)) * (2.0 / L0)) @ R.T + t.to(p.dtype)

    def mesh_world(self, x: torch.Tensor, discrete: dict, pose_grad: bool = True) -> TriMesh:
        """The posed mesh (world frame of the target); differentiable in ``x`` for mesh generators (in its
        generator coordinates only, without ``pose_grad``)."""
        if not pose_grad:
            x = torch.cat([x[: self.n], x[self.n:].detach()])
        theta, t, yaw, scale, _ = self.decode(x)
        d = {**self.d0, **discrete}
        theta = self.carry(theta, d)
        if self.gen.kind == "mesh":
            m = self.gen.mesh(theta.to(self.dtype), d, self.s.lod)
            if self.s.subdivide is not None:
                m = self._subdivided(m)
        else:
            values = self.gen.spec.from_vector(theta.detach().double(), d)
            m = self.gen.to_mesh(values, resolution=self.s.resolution)
        return TriMesh(self._to_world(m.verts.to(self.dtype), t, yaw, scale, d), m.faces, m.groups, m.group_names)

    def _subdivided(self, m: TriMesh) -> TriMesh:
        """``m`` subdivided as the settings say (``FitSettings.subdivide``); every face's four children
        keep its group (libigl numbers them four by four)."""
        from ipm.subdiv import SCHEMES

        levels = self.s.subdivide_levels
        v, f = SCHEMES.get(self.s.subdivide).subdivide(m.verts, m.faces.cpu().numpy(), levels)
        groups = None if m.groups is None else m.groups.repeat_interleave(4 ** levels)
        return TriMesh(v, torch.as_tensor(f, device=m.faces.device), groups, m.group_names)

    def sdf_world(self, x: torch.Tensor, discrete: dict):
        """(f(points) -> distances in the world frame, lo (3,), hi (3,)) for SDF generators."""
        theta, t, yaw, scale, _ = self.decode(x)
        d = {**self.d0, **discrete}
        theta = self.carry(theta, d)
        tree = self.gen.tree_for(d)
        th = theta.to(self.dtype)
        c0, L0 = self.frame(d)
        k = L0 / 2.0
        R = rot_y(yaw).to(self.dtype)
        sc = scale.to(self.dtype)

        def f(p):
            local = ((p - t.to(p.dtype)) @ R.to(p.dtype)) / (sc.to(p.dtype) / k) + c0.to(p.dtype)
            return tree.sdf(th.to(p.dtype), local) * (sc.to(p.dtype) / k)

        lo, hi = tree.with_theta(theta.detach().double()).bounds()
        r = float(np.linalg.norm(np.maximum(np.abs(lo - c0.numpy()), np.abs(hi - c0.numpy())))) / k
        r *= float(scale.detach())
        c = t.detach().double().numpy()
        return f, c - r, c + r

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
    def render_soft(self, x: torch.Tensor, discrete: dict, mesh: TriMesh | None = None) -> torch.Tensor:
        """Soft silhouettes ``(K, H, W)`` of the posed shape in every view (``mesh``: the posed mesh of a mesh
        generator, if already made)."""
        cams = self.cameras(x)
        k = self.sigma_factor
        if self.gen.kind == "mesh":
            from ipm.render.soft import soft_silhouette

            m = self.mesh_world(x, discrete) if mesh is None else mesh
            sig = (self.s.sigma or 1.0) * k  # 1 px^2: the renderer's default
            return torch.stack([soft_silhouette(m.verts, m.faces, c.to(self.dtype), sigma=sig) for c in cams])
        from ipm.render.sdf_silhouette import default_sigma, sdf_silhouette

        f, lo, hi = self.sdf_world(x, discrete)
        return torch.stack([sdf_silhouette(f, c.to(self.dtype), lo, hi,
                                           sigma=(self.s.sigma or default_sigma(c, lo, hi)) * k) for c in cams])

    def objective(self, x: torch.Tensor, discrete: dict, need_grad: bool):
        x = x.detach().clone().requires_grad_(need_grad)
        with torch.set_grad_enabled(need_grad):
            extras: dict = {}
            if isinstance(self.target, MaskTarget):
                mesh = self.mesh_world(x, discrete) if self.gen.kind == "mesh" else None
                pred = self.render_soft(x, discrete, mesh)
                tgt = self.target.masks.to(pred.dtype)
                loss = self.mask_loss(pred, tgt)
                if self.target.outside_is_background and mesh is not None:
                    loss = loss + OUTSIDE_WEIGHT * outside_share(mesh.verts, self.cameras(x))
                if self.target.cues:
                    # part labels do not move the pose (or camera): a periodic pattern (rows of windows)
                    # pulls a shape whose outline is not yet in place towards the nearest period,
                    # wherever that is; the outline places it (on panel5 from one view, Adam with
                    # labels moving the pose lost the start's silhouette IoU 0.82 -> 0.51 in 3 steps)
                    still = (self.mesh_world(x, discrete, pose_grad=False)
                             if self.target.parts is not None and self.use_parts and need_grad else mesh)
                    loss = loss + self._cue_loss(mesh, self.cameras(x), extras, still)
                with torch.no_grad():
                    hard = pred > 0.5
                    t = tgt > 0.5
                    inter = (hard & t).sum((-2, -1)).double()
                    union = (hard | t).sum((-2, -1)).double().clamp(min=1)
                    extras["iou"] = [round(float(v), 5) for v in inter / union]
                    extras["iou_px"] = [[int(a), int(b)] for a, b in zip(inter, union)]
                    extras["area"] = [float(v) for v in pred.sum((-2, -1))]
                    extras["centroid"] = centroids(pred)
                    extras["soft_iou"] = round(float(L.soft_iou_loss(pred, tgt).neg().add(1)), 5)
            else:
                loss = self._mesh_loss(x, discrete)
            if self.s.prior_weight > 0:
                loss = loss + self.s.prior_weight * L.prior_loss(x[: self.n], self.u_ref.to(x.dtype))
            if self.anchored:
                a = self.anchored
                loss = loss + self.s.anchor * (x[a] - self.u_ref[a].to(x)).abs().sum()
            loss = loss + self.part_cost(discrete)
            grad = None
            if need_grad:
                (g,) = torch.autograd.grad(loss, x, allow_unused=True)
                grad = torch.zeros_like(x) if g is None else g * self.pose_mask
        return loss.detach(), grad, extras

    def _cue_loss(self, mesh: TriMesh, cams: list[Camera], extras: dict, parts_mesh: TriMesh) -> torch.Tensor:
        """The weighted cue losses (:mod:`ipm.losses.cues`), each averaged over the views, from one deferred
        render per view (part labels from ``parts_mesh``, the same mesh with the pose held, in cameras
        held); fills ``extras`` with what the tie rule compares: ``depth_px`` (object pixels whose depth
        agrees with the target, per view), ``parts_px`` (per view, per named part, hard intersection and
        union pixels) and the solved ``light`` per view."""
        from ipm.render import deferred as R
        from ipm.render.camera import detach_camera

        t, s = self.target, self.s
        K = len(cams)
        v, f = mesh.verts, mesh.faces
        total = v.sum() * 0.0
        parts = t.parts is not None and self.use_parts
        if parts:
            # the mesh's group of each named part (-2: the mesh has no such part now, e.g. no handle)
            index = [mesh.group_names.index(n) if n in mesh.group_names else -2 for n in t.part_names]
            extras["parts_px"] = []
        if t.depth is not None:
            extras["depth_px"] = []
        if t.image is not None:
            extras["light"] = []
        for i, cam in enumerate(cams):
            cam = cam.to(v.dtype)
            rast = R.rasterize(v, f, cam)
            obj = t.masks[i] > 0.5
            if t.depth is not None:
                d = R.depth(v, f, cam, rast)
                tgt = t.depth[i].to(d.dtype)
                total = total + s.depth_weight / K * C.depth_loss(d, rast.mask, tgt, obj, self.depth_scales[i])
                with torch.no_grad():
                    extras["depth_px"].append(C.depth_agreement(d, rast.mask, tgt, obj, self.depth_scales[i]))
            if parts:
                soft = self._soft_parts(parts_mesh, rast, detach_camera(cam), index)  # (P, H, W)
                want = torch.stack([t.parts[i] == k for k in range(len(index))]).to(v.dtype)
                total = total + s.parts_weight / K * C.parts_loss(soft, want)
                with torch.no_grad():
                    labels = R.part_labels(mesh.groups, rast)
                    hard, w = torch.stack([labels == j for j in index]), want > 0.5
                    extras["parts_px"].append([[int((a & b).sum()), int((a | b).sum())] for a, b in zip(hard, w)])
            if t.image is not None:
                normal = R.vertex_normal_image(v, f, rast)
                loss, light = C.shading_loss(normal, t.image[i].to(v.dtype), rast.mask & obj)
                total = total + s.image_weight / K * loss
                extras["light"].append(light)
        return total

    def _soft_parts(self, mesh: TriMesh, rast, cam: Camera, index: list[int]) -> torch.Tensor:
        """Soft masks ``(P, H, W)`` of the parts ``index`` (mesh groups; -2: absent): the soft silhouette
        of each part's faces that are visible in the exact raster ``rast``, at the fit's blur.

        Not the antialiased part labels: a building's windows are a few pixels of many small faces
        (frames, reveals), where antialiasing's pixel-pair gradient is dominated by which pairs exist
        (measured on panel5 at 192 px: directional derivatives off the finite differences by 5x and in
        sign), while these match float64 finite differences to 1 %. A face half hidden by another
        counts whole. The blur is :data:`PARTS_SIGMA` throughout: target labels are hard, and the 0.5
        level of a wider blur lies outside a small part's outline (panel5 at 160 px, windows of 3 px: at
        1 px^2 the true counts scored 0.34, no better than 6 floors' 0.32)."""
        from ipm.render.soft import soft_silhouette

        v, f = mesh.verts, mesh.faces
        visible = torch.zeros(f.shape[0], dtype=torch.bool, device=f.device)
        visible[rast.face[rast.mask]] = True
        sig = PARTS_SIGMA
        out = []
        for j in index:
            sel = visible & (mesh.groups == j) if mesh.groups is not None and j >= 0 else visible & False
            if not bool(sel.any()):
                out.append(torch.zeros(rast.shape, dtype=v.dtype, device=v.device) + v.sum() * 0.0)
            else:
                out.append(soft_silhouette(v, f[sel], cam, sigma=sig))
        return torch.stack(out)

    def _mesh_loss(self, x: torch.Tensor, discrete: dict) -> torch.Tensor:
        if self.gen.kind == "mesh":
            m = self.mesh_world(x, discrete)
            key = (tuple(sorted(discrete.items())), m.n_faces)
            if key not in self._samplers:
                gen_t = torch.Generator().manual_seed(self.s.seed + 1)
                self._samplers[key] = L.SurfaceSampler.draw(m.verts, m.faces, self.target.samples, gen_t)
            pts = self._samplers[key].points(m.verts)
            return L.chamfer_loss(pts, self.target_pts.to(pts.dtype))
        f, _, _ = self.sdf_world(x, discrete)
        return (L.sdf_surface_loss(f(self.target_pts)) +
                0.1 * L.occupancy_loss(f(self.vol_pts), self.vol_inside))
