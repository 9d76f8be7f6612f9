"""Fitting a generator to silhouette masks or to a mesh: the problem, its initialization, the search,
and the run's files.

The optimizer works on one normalized vector ``x`` in [0, 1]^m and a dict of discrete values:

    x = [ free generator parameters (normalized by their bounds)
        | object pose: translation (3), rotation about the up axis, log2 of a uniform scale
        | camera (with ``camera="fit"``): elevation, distance, vertical field of view ]

The generator's output is first brought to a canonical frame (bounding-box center at the origin, longest
side 2, measured once on the starting shape), then posed; a mesh target's fit starts with the scale that
gives the starting shape the target's bounding sphere. One evaluation is one render of every view plus
the loss (or, for a mesh target, one loss).
"""

from __future__ import annotations

import logging
import math
import time
from collections.abc import Callable, Mapping
from dataclasses import asdict, dataclass, field
from typing import Any

import numpy as np
import torch

from ipm import losses as L
from ipm.optim import discrete as D
from ipm.optim import gradient as G
from ipm.optim.evaluator import Best, BudgetExhausted, Evaluator
from ipm.params import dataclass_from
from ipm.types import Camera, FitResult, TriMesh

log = logging.getLogger(__name__)

T_RANGE = 1.5          # translation in normalized units: [-1.5, 1.5]
LOG2S_RANGE = 2.0      # uniform scale in [1/4, 4]
# yaw in [-360, 360] degrees: starts are wrapped into [-180, 180), so a refinement can turn either way
# by half a turn without meeting the bound
YAW_RANGE = 360.0
# Default Adam steps in normalized parameter space (generators may set ``mask_lr``; ``--lr`` overrides)
MASK_LR = 0.02
MESH_LR = 0.02
# blur of the final refinement of mesh generators, relative to the search's: 0.03 px^2 by default,
# where the soft silhouette's 0.5 level lies within about 0.2 px of the hard one (measured on the
# teacup-to-mug test: final exact IoU 0.96 with 0.15, 0.98 with 0.03)
POLISH_SIGMA_FACTOR = 0.03
# The tie rule (break_ties): a discrete value set back to the preset's ties when, at the same continuous
# values and pose, no view's silhouette (soft > 0.5) gains or loses more than this share of the view's
# target pixels (net, inside and outside the target; one pixel always may). Pixels, not the loss: the
# dishes mug with its handle hidden behind the body (tests/test_fit_ties.py, part_difference)
# has the same silhouettes with and without it (0 px at 64, 96 and 256 px, elevations 0-25 deg, blurs
# of 1 and 0.03 px^2), but soft-IoU losses apart by up to 4.5e-4 (1.2 %, 10 pixels' worth at 256 px):
# soft silhouettes are not quite 1 inside (0.94 at the polish's blur) and a hidden part's layers fill
# them. A hidden part that re-triangulates the surface (the building's back windows, inside its
# outline; panel5 and house2 from four sides) moves up to 0.024 % of the pixels at the polish's blur
# (0.5 % at the search's: the tie is decided at the blur the fit ends with); the smallest visible part
# measured, the building's porch from the front at 256 px, 0.14 %.
TIE_SHARE = 0.0005
ELEV = (-10.0, 80.0)   # camera fit: elevation in degrees
DIST = (1.5, 10.0)     # camera fit: distance from the target point
FOV = (10.0, 90.0)     # camera fit: vertical field of view in degrees
CAMERA_MODES = ("known", "fit")


@dataclass
class MaskTarget:
    """Silhouettes to match: ``masks (K, H, W)`` float in [0, 1] and one camera per view (``camera="fit"``
    uses only their image sizes)."""

    masks: torch.Tensor
    cameras: list[Camera]

    def __post_init__(self):
        if self.masks.ndim != 3:
            raise ValueError(f"masks: expected (K, H, W), got {tuple(self.masks.shape)}")
        if len(self.cameras) != self.masks.shape[0]:
            raise ValueError(f"expected one camera per mask, got {len(self.cameras)} cameras for "
                             f"{self.masks.shape[0]} masks")
        for i, m in enumerate(self.masks):
            frac = float((m > 0.5).float().mean())
            if frac == 0.0:
                raise ValueError(f"mask {i} is empty (no foreground pixel)")
            if frac == 1.0:
                raise ValueError(f"mask {i} is all foreground: the object must fit inside the image")


@dataclass
class MeshTarget:
    """A mesh to match (normalized to DESIGN.md's frame when loaded)."""

    mesh: TriMesh
    samples: int = 4000


@dataclass
class FitSettings:
    """Everything a fit can be told. Defaults are what ``ipm fit`` uses."""

    budget: int = 1500
    seed: int = 0
    discrete: str = "memetic"        # memetic | nlopt | enumerate | none
    camera: str = "known"            # known | fit
    loss: str = "iou"                # iou | mse (masks); chamfer for mesh targets is automatic
    local: str = "adam"              # adam | mma | lbfgs
    lr: float | None = None          # Adam step in normalized space; None: the generator's (see fit_lr)
    sigma: float = 0.0               # soft rasterizer blur; 0 = the renderer's default for the image size
    preset: str | None = None        # start from this preset (default: the generator's defaults)
    free: list[str] | None = None    # continuous parameters to fit (default: all)
    fix: dict = field(default_factory=dict)   # parameters held at given values
    ranges: dict = field(default_factory=dict)  # discrete parameter -> [lo, hi]: search only these values
    pose: bool = True
    prior_weight: float = 0.0        # pull towards the starting preset in normalized space
    polish: float = 0.15             # share of the budget kept for the final gradient refinement
    coarse_to_fine: bool = True      # silhouettes: hold the generator's detail parameters during the search
    lod: Any = None
    resolution: int = 128            # SDF generators: meshing of the result
    ties: bool = True                # discrete values the input cannot tell apart go to the preset's (break_ties)
    memetic: D.MemeticSettings = field(default_factory=D.MemeticSettings)
    nlopt: D.NloptSettings = field(default_factory=D.NloptSettings)

    def __post_init__(self):
        # nested settings may come as dicts (JSON run files, experiment TOML, the Python API)
        for name, cls in (("memetic", D.MemeticSettings), ("nlopt", D.NloptSettings)):
            v = getattr(self, name)
            if isinstance(v, dict):
                setattr(self, name, dataclass_from(cls, v, f"{name} settings", "setting(s)"))

    def check(self) -> None:
        if self.budget < 1:
            raise ValueError(f"budget: expected at least 1 evaluation, got {self.budget}")
        if self.discrete not in D.STRATEGIES:
            raise ValueError(f"discrete search: expected one of {', '.join(D.STRATEGIES)}, got {self.discrete!r}")
        if self.camera not in CAMERA_MODES:
            raise ValueError(f"camera: expected known or fit, got {self.camera!r}")
        if self.loss not in L.LOSSES:
            raise ValueError(f"loss: expected one of {', '.join(L.LOSSES)}, got {self.loss!r}")
        if self.lr is not None and not 0 < self.lr <= 1:
            raise ValueError(f"lr: expected a learning rate in (0, 1], got {self.lr}")
        if self.local not in G.LOCAL:
            raise ValueError(f"local optimizer: expected one of {', '.join(G.LOCAL)}, got {self.local!r}")

    def to_json(self) -> dict:
        return asdict(self)


# ----------------------------------------------------------------------------------------------
# The problem: decode x, render, loss
# ----------------------------------------------------------------------------------------------

def _narrowed(p, rng) -> object:
    """Discrete parameter ``p`` with its search range narrowed to ``rng = [lo, hi]`` (within its bounds)."""
    if rng is None:
        return p
    import dataclasses

    if len(rng) != 2 or not all(float(v).is_integer() for v in rng):
        raise ValueError(f"ranges: {p.name}: expected [lo, hi] integers, got {rng}")
    lo, hi = int(rng[0]), int(rng[1])
    if not p.lo <= lo <= hi <= p.hi:
        raise ValueError(f"ranges: {p.name}: expected {p.lo} <= lo <= hi <= {p.hi}, got [{lo}, {hi}]")
    return dataclasses.replace(p, lo=lo, hi=hi, default=min(max(p.default, lo), hi))


def _centroids(masks: torch.Tensor) -> list[list[float]]:
    """Pixel centroids (x, y) of soft masks (K, H, W) (pixel centers at +0.5, row 0 at the top)."""
    K, H, W = masks.shape
    ys = torch.arange(H, dtype=masks.dtype, device=masks.device) + 0.5
    xs = torch.arange(W, dtype=masks.dtype, device=masks.device) + 0.5
    a = masks.sum((-2, -1)).clamp(min=1e-9)
    cx = (masks.sum(-2) * xs).sum(-1) / a
    cy = (masks.sum(-1) * ys).sum(-1) / a
    return [[round(float(x), 4), round(float(y), 4)] for x, y in zip(cx, cy)]


def translation_from_centroids(cams: list[Camera], rendered: list, target: list) -> list[float]:
    """World translation (3,) moving rendered mask centroids onto the target's, by least squares over
    views (one view constrains the two directions parallel to its image plane)."""
    from ipm.render.camera import camera_frame

    rows, rhs = [], []
    for cam, (rx, ry), (tx, ty) in zip(cams, rendered, target):
        frame = camera_frame(cam.to(torch.float64)).numpy()  # rows: right, up, backward
        dist = float((cam.eye - cam.target).double().norm())
        px = dist * 2.0 * math.tan(math.radians(float(cam.fov_deg)) / 2.0) / cam.height  # world size of a pixel
        rows += [frame[0] / px, -frame[1] / px]
        rhs += [tx - rx, ty - ry]
    t, *_ = np.linalg.lstsq(np.array(rows), np.array(rhs), rcond=None)
    return [float(np.clip(v, -T_RANGE, T_RANGE)) for v in t]


def _rot_y(yaw_deg: torch.Tensor) -> torch.Tensor:
    a = yaw_deg * (math.pi / 180.0)
    c, s = torch.cos(a), torch.sin(a)
    z, o = torch.zeros_like(c), torch.ones_like(c)
    return torch.stack([torch.stack([c, z, s]), torch.stack([z, o, z]), torch.stack([-s, z, c])])


class Problem:
    """A generator, a target and the encoding of the search vector (see the module docstring)."""

    def __init__(self, gen, target: MaskTarget | MeshTarget, settings: FitSettings, *, dtype=torch.float32):
        settings.check()
        self.gen, self.target, self.s = gen, target, settings
        # the blur of the soft silhouettes relative to ``settings.sigma``; the polish lowers it, since
        # with a wide blur the 0.5 level of a soft silhouette lies outside the hard one (thin parts
        # such as handles come out too thin against hard masks)
        self.sigma_factor = 1.0
        self.dtype = dtype
        self.device = target.masks.device if isinstance(target, MaskTarget) else target.mesh.verts.device
        self.start = gen.values(settings.preset, settings.fix)
        cont = [p.name for p in gen.spec.continuous]
        free = settings.free if settings.free is not None else [n for n in cont if n not in settings.fix]
        unknown = [n for n in free if n not in cont]
        if unknown:
            raise ValueError(f"free parameters: unknown or not continuous: {', '.join(unknown)}; "
                             f"continuous parameters: {', '.join(cont)}")
        self.free = [cont.index(n) for n in free]
        self.n = len(self.free)
        self.theta0, self.d0 = gen.split(self.start, torch.float64)
        self.lo, self.hi = gen.spec.lower(), gen.spec.upper()
        self.searched = [_narrowed(p, settings.ranges.get(p.name)) for p in gen.spec.discrete
                         if p.name not in settings.fix]
        unknown = sorted(set(settings.ranges) - {p.name for p in self.searched})
        if unknown:
            raise ValueError(f"ranges: not a searched discrete parameter: {', '.join(unknown)}; searched: "
                             f"{', '.join(p.name for p in self.searched) or 'none'}")
        if settings.discrete == "none":
            self.searched = []
        self.d0 = self.clamp_discrete(self.d0)
        self.cam_fit = isinstance(target, MaskTarget) and settings.camera == "fit"
        self.m = self.n + 5 + (3 if self.cam_fit else 0)
        self.pose_mask = torch.ones(self.m, dtype=torch.float64)
        if not settings.pose:
            self.pose_mask[self.n:self.n + 5] = 0
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
        self.search_mask[detail] = 0
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

    # -- encoding --------------------------------------------------------------------------------
    def encode_params(self, theta: torch.Tensor) -> torch.Tensor:
        lo, hi = self.lo[self.free], self.hi[self.free]
        return ((theta[self.free] - lo) / (hi - lo).clamp(min=1e-12)).clamp(0, 1)

    def x0(self, yaw: float = 0.0, scale: float = 1.0, t=(0.0, 0.0, 0.0), camera=None,
           theta: torch.Tensor | None = None) -> torch.Tensor:
        u = self.encode_params(self.theta0 if theta is None else theta)
        yaw = (yaw + 180.0) % 360.0 - 180.0
        pose = torch.tensor([(v / T_RANGE + 1) / 2 for v in t] + [(yaw / YAW_RANGE + 1) / 2,
                            (math.log2(scale) / LOG2S_RANGE + 1) / 2], dtype=torch.float64)
        parts = [u, pose.clamp(0, 1)]
        if self.cam_fit:
            elev, dist, fov = camera or (25.0, 3.2, 40.0)
            parts.append(torch.tensor([(elev - ELEV[0]) / (ELEV[1] - ELEV[0]), (dist - DIST[0]) / (DIST[1] - DIST[0]),
                                       (fov - FOV[0]) / (FOV[1] - FOV[0])], dtype=torch.float64).clamp(0, 1))
        return torch.cat(parts)

    def decode(self, x: torch.Tensor):
        """-> theta (n_all,), translation (3,), yaw (deg), scale, camera triple or None (all torch)."""
        u = x[: self.n]
        theta = self.theta0.to(x.dtype).clone()
        lo, hi = self.lo[self.free].to(x.dtype), self.hi[self.free].to(x.dtype)
        theta = theta.index_put((torch.as_tensor(self.free, dtype=torch.long),), lo + u * (hi - lo))
        p = x[self.n:self.n + 5]
        t = (p[:3] * 2 - 1) * T_RANGE
        yaw = (p[3] * 2 - 1) * YAW_RANGE
        scale = torch.pow(2.0, (p[4] * 2 - 1) * LOG2S_RANGE)
        cam = None
        if self.cam_fit:
            c = x[self.n + 5:]
            cam = (ELEV[0] + c[0] * (ELEV[1] - ELEV[0]), DIST[0] + c[1] * (DIST[1] - DIST[0]),
                   FOV[0] + c[2] * (FOV[1] - FOV[0]))
        return theta, t, yaw, scale, cam

    def clamp_discrete(self, d: Mapping[str, int]) -> dict:
        """``d`` with the searched values moved into their (possibly narrowed) ranges."""
        out = dict(d)
        for p in self.searched:
            if p.name in out:
                out[p.name] = int(min(max(out[p.name], p.lo), p.hi))
        return out

    def values(self, x: torch.Tensor, discrete: Mapping[str, int]) -> dict:
        theta = self.decode(x.detach().double())[0]
        return self.gen.spec.from_vector(theta, {**self.d0, **discrete})

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
        t2 = t + (scale * 2.0 / size) * (c2 - c) @ _rot_y(yaw).T
        out = x.clone()
        out[self.n:self.n + 3] = (t2 / T_RANGE + 1) / 2
        out[self.n + 4] = (torch.log2(scale * size2 / size) / LOG2S_RANGE + 1) / 2
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
        v = (self.gen.mesh(self.theta0, d, self.s.lod).verts.detach().double() if self.gen.kind == "mesh" else
             self.gen.to_mesh(self.gen.spec.from_vector(self.theta0, d), resolution=48).verts.double())
        r0 = float(torch.linalg.vector_norm(v - c0, dim=1).max()) * 2.0 / L0
        return {"scale": r_t / max(r0, 1e-12), "t": tuple(float(x) for x in c_t)}

    def pose_json(self, x: torch.Tensor, discrete: Mapping[str, int] | None = None) -> dict:
        _, t, yaw, scale, cam = self.decode(x.detach().double())
        c0, L0 = self.frame(discrete or {})
        out = {"translation": [float(v) for v in t], "yaw_deg": float(yaw), "scale": float(scale),
               "canonical_center": [float(v) for v in c0], "canonical_size": float(L0)}
        if cam is not None:
            out["camera"] = {"elevation_deg": float(cam[0]), "distance": float(cam[1]), "fov_deg": float(cam[2])}
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
            if self.gen.kind == "mesh":
                v = self.gen.mesh(self.theta0, d, self.s.lod).verts.detach().double()
            else:
                v = self.gen.to_mesh(self.gen.spec.from_vector(self.theta0, d), resolution=48).verts.double()
            if len(v) == 0:
                raise ValueError(f"{self.gen.name}: the starting parameters give an empty shape for {d}")
            lo, hi = v.min(0).values, v.max(0).values
            # the longest side, not the bounding sphere: a part that widens the box sideways (a handle) then
            # leaves the body's size alone when a search switches it on (with the sphere's diameter, enumerate
            # lost the tall mug's handle: tests/test_fit_generators.py)
            self._frames[key] = (0.5 * (lo + hi), float((hi - lo).max()))
        return self._frames[key]

    def _to_world(self, p: torch.Tensor, t, yaw, scale, discrete: Mapping[str, int]) -> torch.Tensor:
        c0, L0 = self.frame(discrete)
        R = _rot_y(yaw).to(p.dtype)
        return scale.to(p.dtype) * ((p - c0.to(p.dtype)) * (2.0 / L0)) @ R.T + t.to(p.dtype)

    def mesh_world(self, x: torch.Tensor, discrete: dict) -> TriMesh:
        """The posed mesh (world frame of the target); differentiable in ``x`` for mesh generators."""
        theta, t, yaw, scale, _ = self.decode(x)
        d = {**self.d0, **discrete}
        if self.gen.kind == "mesh":
            m = self.gen.mesh(theta.to(self.dtype), d, self.s.lod)
        else:
            values = self.gen.spec.from_vector(theta.detach().double(), d)
            m = self.gen.to_mesh(values, resolution=self.s.resolution)
        return TriMesh(self._to_world(m.verts.to(self.dtype), t, yaw, scale, d), m.faces, m.groups, m.group_names)

    def sdf_world(self, x: torch.Tensor, discrete: dict):
        """(f(points) -> distances in the world frame, lo (3,), hi (3,)) for SDF generators."""
        theta, t, yaw, scale, _ = self.decode(x)
        d = {**self.d0, **discrete}
        tree = self.gen.tree_for(d)
        th = theta.to(self.dtype)
        c0, L0 = self.frame(d)
        k = L0 / 2.0
        R = _rot_y(yaw).to(self.dtype)
        sc = scale.to(self.dtype)

        def f(p):
            local = ((p - t.to(p.dtype)) @ R.to(p.dtype)) / (sc.to(p.dtype) / k) + c0.to(p.dtype)
            return tree.sdf(th.to(p.dtype), local) * (sc.to(p.dtype) / k)

        lo, hi = tree.with_theta(theta.detach().double()).bounds()
        r = float(np.linalg.norm(np.maximum(np.abs(lo - c0.numpy()), np.abs(hi - c0.numpy())))) / k
        r *= float(scale.detach())
        c = t.detach().double().numpy()
        return f, c - r, c + r

    def cameras(self, x: torch.Tensor) -> list[Camera]:
        cams = self.target.cameras
        if not self.cam_fit:
            return cams
        from ipm.render.camera import orbit_camera

        _, _, _, _, (elev, dist, fov) = self.decode(x)
        c0 = cams[0]
        return [orbit_camera(torch.zeros((), dtype=elev.dtype), elev, dist, fov_deg=fov, width=c0.width,
                             height=c0.height)]

    # -- the objective ---------------------------------------------------------------------------
    def render_soft(self, x: torch.Tensor, discrete: dict) -> torch.Tensor:
        """Soft silhouettes ``(K, H, W)`` of the posed shape in every view."""
        cams = self.cameras(x)
        k = self.sigma_factor
        if self.gen.kind == "mesh":
            from ipm.render.soft import soft_silhouette

            m = self.mesh_world(x, discrete)
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
                pred = self.render_soft(x, discrete)
                tgt = self.target.masks.to(pred.dtype)
                loss = L.LOSSES[self.s.loss](pred, tgt)
                with torch.no_grad():
                    hard = pred > 0.5
                    t = tgt > 0.5
                    inter = (hard & t).sum((-2, -1)).double()
                    union = (hard | t).sum((-2, -1)).double().clamp(min=1)
                    extras["iou"] = [round(float(v), 5) for v in inter / union]
                    extras["iou_px"] = [[int(a), int(b)] for a, b in zip(inter, union)]
                    extras["area"] = [float(v) for v in pred.sum((-2, -1))]
                    extras["centroid"] = _centroids(pred)
                    extras["soft_iou"] = round(float(L.soft_iou_loss(pred, tgt).neg().add(1)), 5)
            else:
                loss = self._mesh_loss(x, discrete)
            if self.s.prior_weight > 0:
                loss = loss + self.s.prior_weight * L.prior_loss(x[: self.n], self.u_ref.to(x.dtype))
            grad = None
            if need_grad:
                (g,) = torch.autograd.grad(loss, x, allow_unused=True)
                grad = torch.zeros_like(x) if g is None else g * self.pose_mask
        return loss.detach(), grad, extras

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


# ----------------------------------------------------------------------------------------------
# Initialization: a coarse grid over pose (and camera), best few kept
# ----------------------------------------------------------------------------------------------

def initial_starts(prob: Problem, ev: Evaluator, keep: int = 4):
    """Rank poses on a grid (yaw; with ``camera="fit"`` also elevation and FOV), scale and translation set
    from mask areas and centroids. Returns (the best ``keep`` starts, the presets posed like the best,
    whether the grid left the yaw undetermined: see :func:`yaw_free`)."""
    d = dict(prob.d0)
    graded = pose_grid(prob, ev, d, keep=keep)
    starts = [(e[1], d) for e in graded] or [(prob.x0(), d)]
    return starts, preset_starts(prob, starts[0][0]), yaw_free(graded)


def pose_grid(prob: Problem, ev: Evaluator, d: dict, x: torch.Tensor | None = None, keep: int = 4
              ) -> list[tuple]:
    """The best ``keep`` poses of the shape with discrete values ``d`` and the generator coordinates of
    ``x`` (default: the start), best first, as :func:`spread_starts` entries ``(loss, x, yaw, camera)``."""
    ev.phase = ev.phase if x is not None else "init"
    theta = None if x is None else prob.decode(x.detach().double())[0]
    yaws = [0.0, 45.0, 90.0, 135.0, 180.0, 225.0, 270.0, 315.0] if prob.s.pose else [0.0]
    cams = [None]
    if prob.cam_fit:
        cams = [(e, 3.2, f) for e in (5.0, 25.0, 45.0) for f in (25.0, 40.0, 60.0)]
    scored = []
    for cam in cams:
        for yaw in yaws:
            if ev.remaining <= 1:
                break
            xp = prob.x0(yaw=yaw, camera=cam, theta=theta, **prob.mesh_start(d))
            if isinstance(prob.target, MaskTarget) and prob.s.pose:
                loss, _ = ev(xp, d, grad=False)
                area, cen = ev.last.get("area"), ev.last.get("centroid")
                tgt = prob.target.masks.sum((-2, -1))
                if area is not None and min(area) > 0:
                    s = float(np.clip(np.sqrt(float(tgt.mean()) / max(float(np.mean(area)), 1e-9)), 0.26, 3.9))
                    t = (0.0, 0.0, 0.0)
                    if cen is not None:
                        cams_x = prob.cameras(xp)
                        # scaling about the canonical center moves the rendered centroid by a factor s
                        # relative to the image center of the object; the offset is small, so ignore it
                        t = translation_from_centroids(cams_x, cen, _centroids(prob.target.masks))
                    xp = prob.x0(yaw=yaw, scale=s, t=t, camera=cam, theta=theta)
            loss, _ = ev(xp, d, grad=False)
            scored.append((loss, xp, yaw, cam))
    return spread_starts(scored, keep)


def yaw_free(graded: list[tuple], tol: float = 1e-3) -> bool:
    """Whether a pose grid's entries (:func:`pose_grid`) leave the yaw undetermined: three or more poses
    tied with the best, as for a body of revolution (a mug started without its handle)."""
    return len(graded) >= 3 and all(abs(e[0] - graded[0][0]) <= tol * max(abs(graded[0][0]), 1e-12)
                                    for e in graded[:3])


def spread_starts(scored: list[tuple], keep: int, tol: float = 1e-3) -> list[tuple]:
    """The ``keep`` best of ``(loss, x, yaw, camera)`` entries (more if more tie with the best), best
    first; among equal losses (within ``tol``, relative), the yaw farthest from those already kept
    comes first.

    A shape that looks the same from every yaw (a body of revolution: a mug started without its
    handle) leaves the pose to be decided by other discrete values; the kept poses, which
    :func:`ipm.optim.discrete.best_pose` tries for those, should then cover the circle rather than be
    the first few of the grid."""
    rest = sorted(scored, key=lambda e: e[0])
    out: list[tuple] = []
    if rest:  # every pose tied with the best is kept: the grid's spacing is then the search's
        keep = max(keep, sum(e[0] <= rest[0][0] + tol * max(abs(rest[0][0]), 1e-12) for e in rest))

    def gap(e) -> float:
        same = [abs((e[2] - o[2] + 180.0) % 360.0 - 180.0) for o in out if o[3] == e[3]]
        return min(same, default=360.0)

    while rest and len(out) < keep:
        lo = rest[0][0]
        tied = [i for i, e in enumerate(rest) if e[0] <= lo + tol * max(abs(lo), 1e-12)]
        pick = max(tied, key=lambda i: gap(rest[i]))  # max keeps the first of equal gaps: the grid order
        out.append(rest.pop(pick))
    return out


def preset_starts(prob: Problem, x_best: torch.Tensor) -> list[tuple[torch.Tensor, dict]]:
    """The generator's presets (other than the starting one) as (x, discrete), posed like ``x_best``."""
    out = []
    for name in sorted(prob.gen.presets):
        if name == prob.s.preset:
            continue
        vals = prob.gen.values(name, prob.s.fix)
        th, dd = prob.gen.split(vals, torch.float64)
        out.append((torch.cat([prob.encode_params(th), x_best[prob.n:]]), dict(dd)))
    return out


# ----------------------------------------------------------------------------------------------
# The whole fit
# ----------------------------------------------------------------------------------------------

def fit_lr(gen, target: MaskTarget | MeshTarget, settings: FitSettings) -> float:
    """The Adam step: ``settings.lr`` if given, else the generator's ``mask_lr`` for silhouettes and
    :data:`MESH_LR` for mesh targets."""
    if settings.lr is not None:
        return float(settings.lr)
    if not isinstance(target, MaskTarget):
        return MESH_LR
    return float(getattr(gen, "mask_lr", None) or MASK_LR)


def run_fit(gen, target: MaskTarget | MeshTarget, settings: FitSettings, *, sink: Callable[[dict], None] | None = None,
            replay=(), progress: Callable[[Evaluator], None] | None = None) -> tuple[FitResult, Problem, dict]:
    """Search, then polish; returns (FitResult, the problem, the best point ``{"x", "discrete"}``)."""
    import nlopt

    prob = Problem(gen, target, settings)
    rng = np.random.default_rng(settings.seed)
    torch.manual_seed(settings.seed)
    nlopt.srand(settings.seed)  # GN_CRS2_LM, GN_ESCH and GN_ISRES are stochastic

    ev = Evaluator(prob.objective, settings.budget, sink=sink, replay=replay, progress=progress)
    t0 = time.perf_counter()
    E = ev
    try:
        starts, presets, free_yaw = initial_starts(prob, E)
    except BudgetExhausted:
        starts, free_yaw = [(prob.x0(), dict(prob.d0))], False
        presets = preset_starts(prob, starts[0][0])
    searched = {p.name for p in prob.searched}

    def pose_search(x: torch.Tensor, d: dict) -> torch.Tensor:
        # the start looked the same from every yaw, so its poses say nothing about where, say, a
        # handle switched on by the search should point: rank the pose grid again with it
        graded = pose_grid(prob, E, d, x, keep=1)
        return graded[0][1] if graded else x

    space = D.Space(prob.m, np.asarray(prob.coarse, dtype=np.int64), list(prob.searched), starts,
                    fixed_discrete={k: v for k, v in prob.d0.items() if k not in searched},
                    presets=[(x, prob.clamp_discrete({**prob.d0, **{k: v for k, v in d.items() if k in searched}}))
                             for x, d in presets],
                    pose_search=pose_search if free_yaw and not prob.cam_fit else None)

    lr = fit_lr(gen, target, settings)

    search_lr = lr
    if settings.discrete == "memetic" and settings.memetic.lr is not None:
        search_lr = float(settings.memetic.lr)

    def refine(x, d, steps):
        if ev.remaining <= 0:
            raise BudgetExhausted
        return G.refine(E, x, d, min(steps, ev.remaining), settings.local, search_lr, mask=prob.search_mask)

    polish = int(settings.budget * settings.polish)
    # the tie rule's evaluations (one per searched discrete value) are kept from the polish; those it
    # does not need go back to the winner
    n_tie = len(prob.searched) if settings.ties and isinstance(target, MaskTarget) else 0
    ev.budget = max(ev.count + 1, settings.budget - polish)
    strategy = D.STRATEGIES[settings.discrete]
    if settings.discrete == "none" or not space.discrete:
        D.multistart(E, space, refine, rng)
    else:
        kwargs = {"settings": settings.memetic} if settings.discrete == "memetic" else (
            {"settings": settings.nlopt} if settings.discrete == "nlopt" else {})
        strategy(E, space, refine, rng, **kwargs)
    ev.budget = settings.budget - n_tie
    # Polish: the two best discrete candidates share what is left (close competitors are often only
    # separated after longer refinement), then the best of all gets the rest.
    leaders = ev.leaders(2) if space.discrete else ev.leaders(1)
    if isinstance(target, MaskTarget) and gen.kind == "mesh" and ev.remaining > 0:
        prob.sigma_factor = POLISH_SIGMA_FACTOR
        ev.forget_best()  # the leaders are re-evaluated with the finer blur by their refinement
    for i, lead in enumerate(leaders):
        if ev.remaining <= 0:
            break
        ev.phase = f"polish:{i}"
        share = ev.remaining // (len(leaders) - i)
        try:
            G.refine(E, lead.x, lead.discrete, share, settings.local, lr / 2, mask=prob.pose_mask)
        except BudgetExhausted:
            break
    ev.budget = settings.budget
    x, d, loss = ev.best.x, ev.best.discrete, ev.best.loss
    tied: tuple[str, ...] = ()
    if x is None:  # a budget too small for a single evaluation of the search
        x, d = starts[0][0], dict(prob.d0)
    elif n_tie:
        x, d, loss, tied = break_ties(prob, E, ev.best)
    if ev.remaining > 0 and math.isfinite(loss):
        ev.phase = "polish:final"
        xr, lf = G.refine(E, x, d, ev.remaining, settings.local, lr / 2, mask=prob.pose_mask)
        if lf < loss:
            x, loss = xr, lf
    best = {"x": x, "discrete": d}
    result = FitResult(generator=gen.name, params=prob.values(x, d), loss=float(loss), evaluations=ev.count,
                       wall_time_s=time.perf_counter() - t0, tied=tied)
    return result, prob, best


def break_ties(prob: Problem, ev: Evaluator, winner: Best) -> tuple[torch.Tensor, dict, float, tuple[str, ...]]:
    """The tie rule: searched discrete values that the input views cannot tell apart go back to the
    preset's.

    Discrete parts that no input view shows (a handle hidden behind the body) are a property of the
    input, not a failure of the search: any value fits them, and the fit keeps the one it started from
    (``prob.d0``: the preset's, or the generator's defaults). Each searched discrete value of the
    winner that differs from the starting one is set back to it, and the shape is evaluated once at the
    winner's continuous values and world pose (:meth:`Problem.repose`). If no view's silhouette gains
    or loses more than :data:`TIE_SHARE` of that view's target pixels against the winner's (in its
    intersection and in its union with the target), the value stays set back.

    Only discrete values are compared, at equal continuous values, never continuous ones: the losses
    of separately refined candidates differ by the search's progress (the two handle values of a mug
    fit of 150 evaluations ended 4.6 % apart with the handle hidden), which no tolerance tells from a
    visible difference, and the soft loss alone moves with a hidden part too (see :data:`TIE_SHARE`).
    Values are set back one at a time in the generator's order, each compared with the winner, so
    where only some tie the result is the tied combination closest to the preset found that way. A
    part the winner lacks is tried where the winner's continuous values put it; if it shows there, it
    does not tie. Silhouette targets only (a mesh target shows every part).

    Returns (x (m,), discrete values, loss, names of the parameters set back to the preset's values).
    """
    x, d, loss = winner.x, winner.discrete, winner.loss
    ref = winner.extras.get("iou_px")
    back = [p.name for p in prob.searched if d.get(p.name) != prob.d0.get(p.name)]
    if ref is None or not back:
        return x, d, loss, ()
    allowed = [max(1.0, TIE_SHARE * float(n)) for n in (prob.target.masks > 0.5).sum((-2, -1))]
    tied: list[str] = []
    for name in back:
        cand = {**d, name: prob.d0[name]}
        ev.phase = f"ties:{name}"
        xc = prob.repose(winner.x, winner.discrete, cand)
        try:
            lc, _ = ev(xc, cand, grad=False)
        except BudgetExhausted:
            break
        moved = [abs(a[0] - b[0]) + abs(a[1] - b[1]) for a, b in zip(ev.last["iou_px"], ref)]
        same = all(m <= a for m, a in zip(moved, allowed))
        log.info("tie rule: %s=%s -> %s: loss %.6g -> %.6g, silhouettes moved by %s px (%s)", name, d[name],
                 cand[name], loss, lc, moved, "a tie" if same else "no tie")
        if same:
            x, d, loss = xc, cand, lc
            tied.append(name)
    return x, d, loss, tuple(tied)


def hard_scores(prob: Problem, best: dict) -> dict:
    """Exact per-view mask IoUs of the final shape (hard rasterizer) against the target masks."""
    from ipm.metrics import mask_iou
    from ipm.render.raster import rasterize_mesh

    if not isinstance(prob.target, MaskTarget):
        return {}
    mesh = prob.mesh_world(best["x"].to(torch.float64), best["discrete"]).detach()
    out = []
    for cam, tgt in zip(prob.cameras(best["x"].to(torch.float64)), prob.target.masks):
        mask = rasterize_mesh(mesh, cam).mask.cpu().numpy()
        out.append(mask_iou(mask, tgt.cpu().numpy() > 0.5))
    return {"iou_per_view": out, "iou_mean": float(np.mean(out))}
