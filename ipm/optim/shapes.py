"""What a fit poses and renders: one protocol, :class:`Shape`, with one adapter per kind of generator.

A fit needs, of its generator: the vertices of a shape at given parameters (to measure its canonical frame,
:meth:`ipm.optim.problem.Problem.frame`), the posed shape as a mesh (differentiable where the generator's
mesh is), its soft silhouettes in the target's cameras, and its distance to a target mesh. The adapters are
the only code of the fit that knows whether the generator makes meshes (:class:`MeshShape`: the generator's
mesh, subdivided where ``FitSettings.subdivide`` says so, by the same sparse operator as ``ipm jacobian
--subdivide``) or signed distances (:class:`SdfShape`: the field, its silhouettes those of a marching-cubes
mesh made differentiable by the implicit function theorem, or sphere-traced; meshed by marching cubes for
pictures). A new kind of generator is one new adapter class registered in :data:`SHAPES`.

A :class:`Pose` maps the generator's coordinates to the world: its canonical frame (bounding-box center
``center``, longest side ``size``) to the origin and a longest side of 2, then scaled by ``scale``, turned by
``yaw`` degrees about +y and moved by ``t``.
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from dataclasses import dataclass
from typing import Protocol

import numpy as np
import torch

from ipm import losses as L
from ipm.registry import Registry
from ipm.types import Camera, TriMesh

# blur of the polish of silhouette fits, relative to the search's: 0.03 px^2 by default, where the soft
# silhouette's 0.5 level lies within about 0.2 px of the hard one (measured on the teacup-to-mug test: final
# exact IoU 0.96 with 0.15, 0.98 with 0.03)
POLISH_SIGMA_FACTOR = 0.03


def rot_y(yaw_deg: torch.Tensor) -> torch.Tensor:
    """Rotation ``(3, 3)`` about +y by ``yaw_deg`` degrees (0-dim tensor), differentiable."""
    a = yaw_deg * (math.pi / 180.0)
    c, s = torch.cos(a), torch.sin(a)
    z, o = torch.zeros_like(c), torch.ones_like(c)
    return torch.stack([torch.stack([c, z, s]), torch.stack([z, o, z]), torch.stack([-s, z, c])])


@dataclass(frozen=True)
class Pose:
    """Canonical frame (``center (3,)``, ``size``) to world: translation ``t (3,)``, ``yaw`` (degrees, 0-dim)
    and ``scale`` (0-dim), all differentiable tensors (see the module docstring)."""

    t: torch.Tensor
    yaw: torch.Tensor
    scale: torch.Tensor
    center: torch.Tensor
    size: float

    def to_world(self, p: torch.Tensor) -> torch.Tensor:
        """Points ``(..., 3)`` of the generator's coordinates in the world (their dtype)."""
        R = rot_y(self.yaw).to(p.dtype)
        return self.scale.to(p.dtype) * ((p - self.center.to(p.dtype)) * (2.0 / self.size)) @ R.T + self.t.to(p.dtype)


class Shape(Protocol):
    """What a fit needs of a generator (module docstring)."""

    #: faces with part groups: depth, part labels, shading and outside-the-crop terms apply
    has_faces: bool
    #: the polish's blur relative to the search's
    polish_sigma: float

    def vertices(self, theta: torch.Tensor, discrete: Mapping[str, int]) -> torch.Tensor:
        """``(V, 3)`` float64, detached: the shape's vertices in the generator's coordinates (frames)."""

    def world_mesh(self, theta: torch.Tensor, discrete: Mapping[str, int], pose: Pose) -> TriMesh:
        """The posed shape as a mesh (differentiable in ``theta`` and the pose where the adapter can be)."""

    def silhouettes(self, theta: torch.Tensor, discrete: Mapping[str, int], pose: Pose, cams: list[Camera],
                    sigma_factor: float, mesh: TriMesh | None) -> torch.Tensor:
        """Soft silhouettes ``(K, H, W)`` in ``cams`` (``mesh``: the posed mesh if already made)."""

    def target_loss(self, theta: torch.Tensor, discrete: Mapping[str, int], pose: Pose, target) -> torch.Tensor:
        """0-dim: the distance to a :class:`~ipm.optim.targets.MeshTarget`'s surface (and inside)."""


def target_points(target, dtype: torch.dtype, seed: int) -> torch.Tensor:
    """``(samples, 3)``: points on a mesh target's surface, drawn with ``seed``."""
    gen_t = torch.Generator().manual_seed(seed)
    tv, tf = target.mesh.verts.to(dtype), target.mesh.faces
    return L.SurfaceSampler.draw(tv, tf, target.samples, gen_t).points(tv)


class MeshShape:
    """A mesh generator's output, subdivided where the settings say so (:mod:`ipm.subdiv`)."""

    has_faces = True
    polish_sigma = POLISH_SIGMA_FACTOR

    def __init__(self, gen, settings, dtype: torch.dtype):
        self.gen, self.s, self.dtype = gen, settings, dtype
        self._samplers: dict = {}
        self._target: torch.Tensor | None = None

    def vertices(self, theta, discrete):
        """The generator's mesh vertices ``(V, 3)`` float64, detached, before subdivision."""
        return self.gen.mesh(theta, discrete, self.s.lod).verts.detach().double()

    def canonical(self, theta: torch.Tensor, discrete: Mapping[str, int]) -> TriMesh:
        """The generator's mesh (subdivided as the settings say; every face's four children keep its group,
        libigl numbers them four by four) in its own coordinates."""
        m = self.gen.mesh(theta.to(self.dtype), discrete, self.s.lod)
        if self.s.subdivide is None:
            return m
        from ipm.subdiv import SCHEMES

        levels = self.s.subdivide_levels
        v, f = SCHEMES.get(self.s.subdivide).subdivide(m.verts, m.faces.cpu().numpy(), levels)
        groups = None if m.groups is None else m.groups.repeat_interleave(4 ** levels)
        return TriMesh(v, torch.as_tensor(f, device=m.faces.device), groups, m.group_names)

    def world_mesh(self, theta, discrete, pose):
        """:meth:`canonical` moved to the world by ``pose`` (differentiable in ``theta`` and the pose)."""
        m = self.canonical(theta, discrete)
        return TriMesh(pose.to_world(m.verts.to(self.dtype)), m.faces, m.groups, m.group_names)

    def silhouettes(self, theta, discrete, pose, cams, sigma_factor, mesh=None):
        """Soft mesh silhouettes ``(K, H, W)``; ``sigma`` is the settings' (default 1 px^2) times ``sigma_factor``."""
        from ipm.render.soft import soft_silhouette

        m = self.world_mesh(theta, discrete, pose) if mesh is None else mesh
        sig = (self.s.sigma or 1.0) * sigma_factor  # 1 px^2: the renderer's default
        return torch.stack([soft_silhouette(m.verts, m.faces, c.to(self.dtype), sigma=sig) for c in cams])

    def target_loss(self, theta, discrete, pose, target):
        """Symmetric Chamfer between points drawn on the posed mesh (fixed samples per topology) and on the target."""
        m = self.world_mesh(theta, discrete, pose)
        key = (tuple(sorted(discrete.items())), m.n_faces)
        if key not in self._samplers:
            gen_t = torch.Generator().manual_seed(self.s.seed + 1)
            self._samplers[key] = L.SurfaceSampler.draw(m.verts, m.faces, target.samples, gen_t)
        pts = self._samplers[key].points(m.verts)
        if self._target is None:
            self._target = target_points(target, self.dtype, self.s.seed)
        return L.chamfer_loss(pts, self._target.to(pts.dtype))


class SdfShape:
    """An SDF generator's field: silhouettes through a differentiable iso-surface mesh (``FitSettings.sdf_silhouette``
    "mesh", the default) or by sphere tracing ("trace"), meshes by marching cubes (not differentiable)."""

    has_faces = False

    def __init__(self, gen, settings, dtype: torch.dtype):
        self.gen, self.s, self.dtype = gen, settings, dtype
        self._target: tuple | None = None
        self.traced = getattr(settings, "sdf_silhouette", "mesh") == "trace"
        self.polish_sigma = 1.0 if self.traced else POLISH_SIGMA_FACTOR
        # ((theta, discrete, spacing), local iso-surface, the tree's box): pose-only changes keep the mesh
        self._iso: tuple | None = None

    def vertices(self, theta, discrete):
        """Vertices ``(V, 3)`` float64 of a coarse marching-cubes mesh (48 samples along the longest side)."""
        return self.gen.to_mesh(self.gen.spec.from_vector(theta, discrete), resolution=48).verts.double()

    def world_mesh(self, theta, discrete, pose):
        """Marching cubes at the settings' resolution, posed; not differentiable (``theta`` is detached)."""
        values = self.gen.spec.from_vector(theta.detach().double(), discrete)
        m = self.gen.to_mesh(values, resolution=self.s.resolution)
        return TriMesh(pose.to_world(m.verts.to(self.dtype)), m.faces, m.groups, m.group_names)

    def field(self, theta: torch.Tensor, discrete: Mapping[str, int], pose: Pose):
        """``(f(points) -> distances in the world frame, lo (3,), hi (3,))``: the posed field and a box
        holding it."""
        tree = self.gen.tree_for(discrete)
        th = theta.to(self.dtype)
        c0, k = pose.center, pose.size / 2.0
        R = rot_y(pose.yaw).to(self.dtype)
        sc, t = pose.scale.to(self.dtype), pose.t

        def f(p):
            local = ((p - t.to(p.dtype)) @ R.to(p.dtype)) / (sc.to(p.dtype) / k) + c0.to(p.dtype)
            return tree.sdf(th.to(p.dtype), local) * (sc.to(p.dtype) / k)

        lo, hi = tree.with_theta(theta.detach().double()).bounds()
        r = float(np.linalg.norm(np.maximum(np.abs(lo - c0.numpy()), np.abs(hi - c0.numpy())))) / k
        r *= float(pose.scale.detach())
        c = t.detach().double().numpy()
        return f, c - r, c + r

    def silhouettes(self, theta, discrete, pose, cams, sigma_factor, mesh=None):
        """Soft silhouettes ``(K, H, W)`` of the posed field (``mesh`` is ignored): of its iso-surface mesh
        (:meth:`mesh_silhouettes`), blur the settings' (squared pixels, default 1) times ``sigma_factor``; or
        sphere-traced, blur the settings' (world units, default half a pixel's footprint) times ``sigma_factor``."""
        from ipm.render import sdf_mesh_silhouette as M
        from ipm.render.sdf_silhouette import default_sigma, sdf_silhouette

        if not self.traced:
            sigma = (self.s.sigma or 1.0) * sigma_factor
            sil = self.mesh_silhouettes(theta, discrete, pose, cams, sigma)
            if sil is not None:
                return sil
            f, lo, hi = self.field(theta, discrete, pose)  # no surface on the grid: traced, at the same blur
            return torch.stack([M.traced_fallback(f, c.to(self.dtype), lo, hi, sigma,
                                                  M.pixel_footprint(c, (lo + hi) / 2), self.dtype) for c in cams])
        f, lo, hi = self.field(theta, discrete, pose)
        return torch.stack([sdf_silhouette(f, c.to(self.dtype), lo, hi,
                                           sigma=(self.s.sigma or default_sigma(c, lo, hi)) * sigma_factor)
                            for c in cams])

    def mesh_silhouettes(self, theta, discrete, pose, cams, sigma: float) -> torch.Tensor | None:
        """Soft silhouettes ``(K, H, W)``, blur ``sigma`` px^2, of the field's iso-surface
        (:mod:`ipm.render.sdf_mesh_silhouette`): marching cubes in the generator's coordinates on a grid of
        :data:`~ipm.render.sdf_mesh_silhouette.CELL_PX` pixels at the pose's scale (kept while only the pose
        changes), vertices differentiable in ``theta`` by the implicit function theorem, posed (differentiable
        in the pose); None where the grid holds no surface."""
        from ipm.render import sdf_mesh_silhouette as M

        tree = self.gen.tree_for(discrete)
        th = theta.to(self.dtype)
        shape_key = (theta.detach().double().cpu().numpy().tobytes(), tuple(sorted(discrete.items())))
        if self._iso is None or self._iso[0][:2] != shape_key:
            lo, hi = tree.with_theta(theta.detach().double()).bounds()
        else:
            lo, hi = self._iso[2]
        to_local = pose.size / 2.0 / float(pose.scale.detach())
        t = pose.t.detach().double().cpu().numpy()
        h = M.grid_spacing(lo, hi, min(M.pixel_footprint(c, t) for c in cams) * to_local)
        if self._iso is None or self._iso[0] != (*shape_key, h):
            iso = M.iso_surface(lambda p: tree.sdf(th.detach(), p), lo, hi, h, dtype=self.dtype)
            self._iso = ((*shape_key, h), iso, (lo, hi))
        iso = self._iso[1]
        if iso.n_faces == 0:
            return None
        local = iso.verts.to(self.dtype)
        cams = [c.to(self.dtype) for c in cams]
        seen = pose.to_world(local).detach()
        parts = [M.interior(seen, iso.faces, c, sigma) for c in cams]
        verts = pose.to_world(M.moved_vertices(lambda p: tree.sdf(th, p), local, [f for _, f in parts]))
        return torch.stack([M.mesh_silhouette(verts, f, c, sigma, deep) for (deep, f), c in zip(parts, cams)])

    def target_loss(self, theta, discrete, pose, target):
        """Mean ``|f|`` at the target's surface points plus 0.1 x the occupancy loss at points in ``[-1.1, 1.1]^3``."""
        if self._target is None:
            from ipm.metrics import inside

            rng = np.random.default_rng(self.s.seed)
            vol = rng.uniform(-1.1, 1.1, size=(target.samples, 3))
            V, F = target.mesh.verts.detach().double().numpy(), target.mesh.faces.numpy()
            self._target = (target_points(target, self.dtype, self.s.seed), torch.as_tensor(vol, dtype=self.dtype),
                            torch.as_tensor(inside(vol, V, F)))
        pts, vol, occupied = self._target
        f, _, _ = self.field(theta, discrete, pose)
        return L.sdf_surface_loss(f(pts)) + 0.1 * L.occupancy_loss(f(vol), occupied)


#: the adapter of each kind of generator (``Generator.kind``): another kind is one more ``SHAPES.add``
SHAPES: Registry[type] = Registry("shape adapter")
SHAPES.add("mesh", MeshShape)
SHAPES.add("sdf", SdfShape)


def shape_for(gen, settings, dtype: torch.dtype) -> Shape:
    """The adapter of ``gen``'s kind."""
    return SHAPES.get(gen.kind)(gen, settings, dtype)
