"""Rendering on the CPU: cameras, differentiable soft silhouettes of meshes and SDFs, exact masks,
depth and normals, and shaded previews.

Shading is kept apart from rasterization: :mod:`~ipm.render.soft` (SoftRas silhouettes of meshes,
differentiable), :mod:`~ipm.render.sdf_mesh_silhouette` (silhouettes of SDFs through a differentiable
iso-surface mesh, the fits' default), :mod:`~ipm.render.sdf_silhouette` (sphere-traced silhouettes, the
reference, and depth and normals of SDFs),
:mod:`~ipm.render.raster` (hard z-buffer for evaluation masks, depth, normals, face ids) and
:mod:`~ipm.render.preview` (Lambert shading into PNG). Camera math lives in :mod:`~ipm.render.camera`.
:mod:`~ipm.render.deferred` is the differentiable deferred renderer in nvdiffrast's four operations
(rasterize, interpolate, antialias, shade): depth, normals, part labels and a shaded image whose
gradients reach the vertex positions, also across silhouette and occlusion edges.
"""

from ipm.render.camera import (
    Intrinsics,
    crop_camera,
    heldout_views,
    input_views,
    intrinsics_camera,
    load_cameras,
    load_intrinsics,
    look_at_camera,
    orbit_camera,
    pixel_rays,
    project,
    projection,
    save_cameras,
    view_matrix,
)
from ipm.render.deferred import DeferredSettings, render_deferred
from ipm.render.raster import Fragments, hard_mask, rasterize
from ipm.render.sdf_silhouette import sdf_depth_normals, sdf_silhouette
from ipm.render.soft import soft_silhouette, soft_silhouettes

__all__ = [
    "DeferredSettings", "Fragments", "Intrinsics", "crop_camera", "hard_mask", "heldout_views", "input_views",
    "intrinsics_camera", "load_cameras", "load_intrinsics", "look_at_camera", "orbit_camera", "pixel_rays",
    "project", "projection", "rasterize", "render_deferred", "save_cameras",
    "sdf_depth_normals", "sdf_silhouette", "soft_silhouette", "soft_silhouettes", "view_matrix",
]
