"""The evaluation protocol v2 of DESIGN.md, the parts that are not metrics: views that must see the whole
target, the one alignment allowed for single-view predictions, and which discrete parts of a generator
target the input views hide.

- **No clipping.** A target whose mask touches the image border in an input or held-out view is refused
  (:func:`check_border`): a method cannot see where a clipped object ends, and a held-out IoU measured on
  a cropped picture is wrong.
- **Scored where placed.** Predictions are scored in the frame of the input cameras. From one view,
  moving an object along the line of sight and scaling it about the eye give the same picture, so for
  K = 1 only, the prediction is scaled about the input camera's eye by the one factor
  ``s in [0.5, 2]`` that minimizes Chamfer-L1 to the target (:func:`align_scale`, a deterministic 1-D
  search). Nothing else is aligned: pose, shape and hidden parts are the method's.
- **Hidden parts.** A discrete value of a generator sample that no input view can show (a handle behind
  the body, a window count inside the outline) is a property of the input: :func:`hidden_discrete`
  lists the discrete parameters one of whose neighbouring values draws the same input masks (and, for
  a method given cues, the same depth maps and part labels).
- **Cues from the exact rasterizer.** Depth maps and part labels of the input views, for methods that
  take them, come from the same exact rasterization as the masks (:func:`render_views`).
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np
import torch

from ipm.errors import InputError
from ipm.metrics import touches_border
from ipm.types import Camera, TriMesh

ALIGN_RANGE = (0.5, 2.0)   # the scale about the eye searched for K = 1 (DESIGN.md)
ALIGN_GRID = 25            # log-spaced scales tried before the bounded Brent refinement
ALIGN_SAMPLES = 4000       # surface samples each way during the search (the final scores use the bench's)
# Share of a view's target pixels that another discrete value may change (one pixel always may) and still
# count as hidden: the fit's tie rule uses the same share (ipm.optim.fit.TIE_SHARE, where the measurements
# are: a handle behind the body moves 0 pixels, a building's back windows up to 0.024 %, the smallest visible
# part measured, a porch at 256 px, 0.14 %).
HIDDEN_TOLERANCE = 0.0005


def check_border(masks: np.ndarray, what: str) -> None:
    """Raise ``ValueError`` naming ``what`` and the first view whose mask (K, H, W) touches the border."""
    for i, m in enumerate(masks):
        if touches_border(m):
            raise InputError(f"{what}: the mask of view {i} touches the image border (the object is clipped); "
                             "expected a target that every protocol view sees whole: normalize it to the "
                             "unit bounding sphere and keep the cameras at distance >= 3.2")


def scale_about(mesh: TriMesh, point: torch.Tensor, s: float) -> TriMesh:
    """The mesh scaled by ``s`` about ``point`` (3,): ``point + s (v - point)``."""
    p = point.to(mesh.verts.dtype).to(mesh.verts.device)
    return TriMesh(p + s * (mesh.verts - p), mesh.faces, mesh.groups, mesh.group_names)


@dataclass(frozen=True)
class Alignment:
    """The K = 1 alignment: the scale about the eye and Chamfer-L1 before and after (search samples)."""

    scale: float
    chamfer_before: float
    chamfer_after: float


def align_scale(pred: TriMesh, target: TriMesh, eye: torch.Tensor, *, n: int = ALIGN_SAMPLES, seed: int = 0,
                bounds: tuple[float, float] = ALIGN_RANGE) -> Alignment:
    """The scale ``s`` in ``bounds`` about ``eye`` (3,) that minimizes Chamfer-L1 between ``pred`` scaled
    by ``s`` and ``target`` (exact point-to-surface distances of ``n`` samples each way).

    Scaling about the eye keeps every sample's direction from the eye, so both AABB trees stay fixed:
    the prediction's samples move (``e + s (p - e)``), and the distance from a target sample ``t`` to the
    scaled prediction is ``s`` times the distance from ``e + (t - e) / s`` to the unscaled one. The search
    is a grid of :data:`ALIGN_GRID` log-spaced scales, then a bounded Brent refinement between the best
    grid point's neighbours; it is deterministic for a given ``seed``.
    """
    from scipy.optimize import minimize_scalar

    from ipm.metrics import mesh_arrays, point_to_surface, sample_surface

    lo, hi = bounds
    if not 0 < lo <= 1 <= hi:
        raise InputError(f"alignment bounds: expected 0 < lo <= 1 <= hi, got {bounds}")
    Vp, Fp = mesh_arrays(pred)
    Vt, Ft = mesh_arrays(target)
    e = eye.detach().cpu().double().numpy()
    rng = np.random.default_rng(seed)
    sp, st = sample_surface(Vp, Fp, n, rng), sample_surface(Vt, Ft, n, rng)

    def chamfer(log_s: float) -> float:
        s = float(np.exp(log_s))
        d_pt = point_to_surface(e + s * (sp - e), Vt, Ft)
        d_tp = s * point_to_surface(e + (st - e) / s, Vp, Fp)
        return 0.5 * (float(d_pt.mean()) + float(d_tp.mean()))

    grid = np.linspace(np.log(lo), np.log(hi), ALIGN_GRID)
    values = [chamfer(g) for g in grid]
    i = int(np.argmin(values))
    a, b = grid[max(i - 1, 0)], grid[min(i + 1, len(grid) - 1)]
    res = minimize_scalar(chamfer, bounds=(a, b), method="bounded", options={"xatol": 1e-5})
    best_log, best = (float(res.x), float(res.fun)) if res.fun < values[i] else (float(grid[i]), values[i])
    return Alignment(float(np.exp(best_log)), chamfer(0.0), best)


def render_masks(mesh: TriMesh, cameras: Sequence[Camera]) -> np.ndarray:
    """Exact silhouettes (K, H, W) bool of ``mesh`` in each camera (the exact rasterizer)."""
    from ipm.render.raster import rasterize_mesh

    return np.stack([rasterize_mesh(mesh, c).mask.cpu().numpy().astype(bool) for c in cameras])


@dataclass(frozen=True)
class Views:
    """What views show of a mesh: masks (K, H, W) bool; depth (K, H, W) float64 view-axis depth in scene
    units, NaN off the object; parts (K, H, W) int64, ``k`` where the visible face belongs to the mesh's
    group ``part_names[k]``, -1 where it shows none of them (background, or another part). ``depth`` and
    ``parts`` are None unless asked for."""

    masks: np.ndarray
    depth: np.ndarray | None = None
    parts: np.ndarray | None = None
    part_names: tuple[str, ...] = ()


def render_views(mesh: TriMesh, cameras: Sequence[Camera], *, depth: bool = False,
                 parts: Sequence[str] = ()) -> Views:
    """Masks and, when asked, depth maps and the labels of the parts named ``parts`` (the mesh's groups,
    as ``ipm render`` writes them), from one exact rasterization per camera (the one :func:`render_masks`
    makes, so the cues cover exactly the masks' pixels). A named part the mesh does not have (a mug
    without a handle) is nowhere. ``InputError`` when ``parts`` are asked of a mesh without groups."""
    from ipm.render.raster import rasterize_mesh, view_maps

    parts = tuple(parts)
    lut = None
    if parts:
        if mesh.groups is None or not mesh.group_names:
            raise InputError(f"part labels {', '.join(parts)}: expected a mesh with named parts (a generator "
                             "sample), got one without")
        # mesh group -> index in ``parts`` (-1: not a named part); the last entry serves empty pixels
        lut = torch.tensor([parts.index(n) if n in parts else -1 for n in mesh.group_names] + [-1],
                           dtype=torch.int64)
    masks, depths, labels = [], [], []
    for cam in cameras:
        maps = view_maps(rasterize_mesh(mesh, cam), mesh)
        masks.append(maps["mask"].cpu().numpy().astype(bool))
        if depth:
            depths.append(maps["depth"].cpu().numpy())
        if lut is not None:
            labels.append(lut.to(maps["groups"].device)[maps["groups"]].cpu().numpy())
    return Views(np.stack(masks), np.stack(depths) if depth else None, np.stack(labels) if parts else None,
                 parts)


def hidden_discrete(gen, values: dict, frame: tuple[np.ndarray, float], cameras: Sequence[Camera],
                    seen: Views, tolerance: float = HIDDEN_TOLERANCE) -> dict[str, list[int]]:
    """Discrete parameters of a generator sample whose neighbouring values (``v - 1``, ``v + 1`` within
    bounds) draw the same input views: ``{name: [those values]}``.

    gen: a mesh generator; values: the sample's parameters; frame: the ``(center, scale)`` that put the
    sample in the protocol's frame (the neighbours get the same one: the object is the same, only a part
    differs); seen: the sample's input views (:func:`render_views`: masks, and the depth and part labels a
    method is given, if any). A pixel differs when its mask does, or, where given, its part label, or its
    depth by more than the depth loss's knee (:data:`ipm.losses.cues.DEPTH_KNEE` of the view's median
    depth, what the fit's tie rule counts). Two view sets are the same when in no view more than
    ``tolerance`` of the sample's pixels in that view differ (one pixel always may).
    """
    from ipm.losses.cues import DEPTH_KNEE

    center, scale = frame
    masks = seen.masks
    allowed = np.maximum(1, (tolerance * masks.sum((1, 2))).astype(np.int64))
    knee = None
    if seen.depth is not None:
        knee = DEPTH_KNEE * np.array([np.median(d[np.isfinite(d)]) for d in seen.depth])[:, None, None]
    out: dict[str, list[int]] = {}
    for p in gen.spec.discrete:
        same = []
        for v in (int(values[p.name]) - 1, int(values[p.name]) + 1):
            if not p.lo <= v <= p.hi:
                continue
            m = gen.to_mesh({**values, p.name: v})
            if m.n_faces == 0:
                continue
            verts = (m.verts.detach().double() - torch.as_tensor(center)) * scale
            other = render_views(TriMesh(verts, m.faces, m.groups, m.group_names), cameras,
                                 depth=seen.depth is not None, parts=seen.part_names)
            differ = other.masks != masks
            if seen.depth is not None:
                both = other.masks & masks
                differ |= both & ~(np.abs(np.nan_to_num(other.depth) - np.nan_to_num(seen.depth)) <= knee)
            if seen.parts is not None:
                differ |= other.parts != seen.parts
            if np.all(differ.sum((1, 2)) <= allowed):
                same.append(v)
        if same:
            out[p.name] = same
    return out
