"""2D inverse modeling: a 2D SDF tree fitted to a binary image, as the shape itself or as the profile of
a body of revolution seen from its side.

``shape``: the image shows the 2D shape (a plan, a logo, a cross-section, the front of an extrusion). The
tree's zero set is placed in the image by a similarity (translation, scale, rotation) and the tree's
continuous parameters and that pose are fitted together.

``profile``: the image shows the side silhouette of the solid ``revolve(tree)`` (the tree's x is the
distance from the vertical axis, its y the height), seen at right angles to the axis from far away
(orthographic). A pixel at signed distance u from the axis is inside that silhouette when some point of
the profile at radius r >= |u| is at its height (a cup's wall at r = 0.45 hides the axis behind it); so the
silhouette's field is the running minimum of the profile's distance over the radii from |u| outwards,
taken along each image row (``torch.cummin``, differentiable: the gradient goes to the minimizing pixel).
The pose is the axis' column, the base's row and the scale (no rotation).

Both: the tree's distance, in pixels, drawn as the soft mask sigmoid(-d / sigma), compared with the mask by
any mask loss (``ipm.losses.mask_loss``: soft IoU, or the transport losses where the start does not overlap
the mask); Adam on the parameters (in units of the start's size) and the pose, from several starts
(``shape``: rotations by quarter turns), each briefly, the best then to the end. The start's pose matches the
tree's area and centroid to the mask's. Parameters stay within their bounds."""

from __future__ import annotations

import math
import time
from dataclasses import dataclass, field
from typing import Annotated, Literal

import numpy as np
import torch
from msgspec import Meta

from ipm import losses as L
from ipm.errors import InputError
from ipm.sdf.tree import Tree

Mode = Literal["shape", "profile"]


@dataclass(frozen=True)
class Fit2DSettings:
    """Settings of :func:`fit_2d` (checked by :meth:`check`)."""

    mode: Mode = "shape"
    steps: Annotated[int, Meta(ge=1, le=100_000, extra={"noun": "a number of steps"})] = 400
    # Adam step of the tree's parameters, share of the start's size per step; the pose's in pixels follows
    lr: Annotated[float, Meta(gt=0, le=1, extra={"noun": "a learning rate"})] = 0.01
    loss: str = "iou"
    transport: L.TransportSettings = field(default_factory=L.TransportSettings)
    # shape mode: starts turned by quarter turns (1: only the tree as it is)
    starts: Annotated[int, Meta(ge=1, le=8, extra={"noun": "a number of starts"})] = 4
    # soft edge of the drawn mask, pixels
    sigma: Annotated[float, Meta(gt=0, le=10, extra={"noun": "a blur in pixels"})] = 0.7

    def check(self) -> Fit2DSettings:
        """The settings themselves if every field is in range and ``loss`` parses; else ``InputError`` naming
        the field."""
        import msgspec

        from ipm.settings_check import first_infinite

        data = {k: getattr(self, k) for k in ("mode", "steps", "lr", "loss", "starts", "sigma")}
        data["transport"] = {f: getattr(self.transport, f) for f in self.transport.__dataclass_fields__}
        try:
            msgspec.convert(data, Fit2DSettings)
        except msgspec.ValidationError as e:
            raise InputError(f"2D fit settings: {e}") from None
        bad = first_infinite(data, Fit2DSettings)
        if bad:
            raise InputError(f"2D fit settings: {'.'.join(bad)}: expected a finite number")
        L.parse_loss(self.loss)
        return self


@dataclass(frozen=True)
class Fit2DResult:
    """A 2D fit: the tree with its fitted values, the pose (pixels: ``tx``, ``ty``, ``scale`` pixels per
    tree unit, ``rotation_deg``), the exact IoU of the drawn shape (``d < 0``) against the mask, the loss,
    the steps and the wall time; ``mask``: the drawn shape (H, W) bool."""

    tree: Tree
    pose: dict
    iou: float
    loss: float
    steps: int
    seconds: float
    mode: str
    mask: np.ndarray

    def to_json(self) -> dict:
        """The fit's summary as JSON: mode, pose, IoU, loss, steps, seconds and the tree's values (``params``)."""
        return {"mode": self.mode, "pose": self.pose, "iou": round(self.iou, 6), "loss": self.loss,
                "steps": self.steps, "seconds": round(self.seconds, 3),
                "params": {k: v for k, v in self.tree.values().items()}}


def _pixels(h: int, w: int, dtype) -> tuple[torch.Tensor, torch.Tensor]:
    """Pixel centres ``(x (h, w), y (h, w))`` in image coordinates (row 0 at the top)."""
    y, x = torch.meshgrid(torch.arange(h, dtype=dtype) + 0.5, torch.arange(w, dtype=dtype) + 0.5, indexing="ij")
    return x, y


def field_2d(tree: Tree, theta: torch.Tensor, pose: torch.Tensor, size: tuple[int, int], mode: str) -> torch.Tensor:
    """The tree's signed distance in pixels at every pixel centre ``(H, W)``: ``pose (4,)`` = (tx, ty,
    log scale, rotation in radians); ``shape``: a point p of the image is the tree's point
    ``R(-rotation) (p - t) / scale`` with y up; ``profile``: the side silhouette of ``revolve(tree)`` with
    its axis at column ``tx`` and its base (y = 0) at row ``ty`` (see the module)."""
    h, w = size
    px, py = _pixels(h, w, theta.dtype)
    s = torch.exp(pose[2])
    u, v = (px - pose[0]) / s, (pose[1] - py) / s
    if mode == "shape":
        c, sn = torch.cos(pose[3]), torch.sin(pose[3])
        q = torch.stack([c * u + sn * v, -sn * u + c * v], -1)
        return tree.sdf(theta, q) * s
    d = tree.sdf(theta, torch.stack([u.abs(), v], -1)) * s
    # running minimum over the radii from |u| outwards, along each row (columns ordered by |u| descending)
    order = torch.argsort(u[0].detach().abs(), descending=True, stable=True)
    run, _ = torch.cummin(d[:, order], dim=1)
    out = torch.empty_like(run)
    out[:, order] = run
    return out


def _moments(mask: torch.Tensor) -> tuple[float, float, float]:
    """(area, centroid x, centroid y) of a soft mask ``(H, W)`` in pixels."""
    h, w = mask.shape
    px, py = _pixels(h, w, mask.dtype)
    a = float(mask.sum())
    return a, float((mask * px).sum()) / max(a, 1e-9), float((mask * py).sum()) / max(a, 1e-9)


def start_pose(tree: Tree, theta: torch.Tensor, target: torch.Tensor, mode: str, rotation: float) -> torch.Tensor:
    """The pose ``(4,)`` that gives the tree (turned by ``rotation`` radians) the mask's area and centroid
    (``profile``: the centroid's column is the axis, and the mask's lowest row the base)."""
    h, w = target.shape
    area, cx, cy = _moments(target)
    # the tree drawn at 1 pixel per unit around the origin, over its bounding box
    lo, hi = tree.bounds()
    span = float(max(np.max(hi - lo), 1e-6))
    k = 64.0 / span  # pixels per unit of a 128 x 128 probe
    probe = torch.tensor([64.0, 64.0, math.log(k), rotation], dtype=theta.dtype)
    mid = 0.5 * (lo + hi)
    if mode == "shape":
        c, sn = math.cos(rotation), math.sin(rotation)
        probe[0] = 64.0 - k * (c * mid[0] - sn * mid[1])
        probe[1] = 64.0 + k * (sn * mid[0] + c * mid[1])
    else:
        probe[1] = 64.0 + k * 0.5 * (lo[1] + hi[1])
    with torch.no_grad():
        inside = (field_2d(tree, theta, probe, (128, 128), mode) < 0).to(theta.dtype)
    a0, x0, y0 = _moments(inside)
    if a0 < 1:
        raise InputError("2D fit: expected a tree whose shape has an area at its starting values, got an empty "
                         "shape")
    s = k * math.sqrt(area / a0)
    f = s / k
    pose = torch.tensor([cx - f * (x0 - probe[0].item()), cy - f * (y0 - probe[1].item()), math.log(s), rotation],
                        dtype=theta.dtype)
    if mode == "profile":
        rows = torch.nonzero(target.sum(1) > 0.5)
        ybase = float(rows.max()) + 1.0 if len(rows) else float(h)
        pose[0] = cx
        pose[1] = ybase + f * 0.0 if lo[1] >= 0 else ybase + s * float(lo[1])
    return pose


def fit_2d(tree: Tree, mask: np.ndarray, settings: Fit2DSettings = Fit2DSettings(), *,
           progress=None) -> Fit2DResult:
    """Fit the 2D ``tree``'s continuous parameters and its pose to ``mask (H, W)`` (bool or [0, 1], the
    shape > 0.5); deterministic. ``progress(step, total, loss)`` is called after each step."""
    settings = Fit2DSettings.check(settings)
    if tree.dim != 2:
        raise InputError(f"2D fit: expected a tree with a 2D root, got a {tree.dim}D tree")
    m = np.asarray(mask)
    if m.ndim != 2 or min(m.shape) < 4:
        raise InputError(f"2D fit: expected a mask of at least 4 x 4 pixels, got shape {m.shape}")
    target = torch.as_tensor(m.astype(np.float64) if m.dtype == bool else m, dtype=torch.float64).clamp(0, 1)
    shape_px = target > 0.5
    if not shape_px.any():
        raise InputError("2D fit: the mask is empty: expected some shape pixels (> 0.5)")
    if shape_px.all():
        raise InputError("2D fit: the mask is all shape: expected some background")
    t0 = time.perf_counter()
    loss_fn = L.mask_loss(settings.loss, **{f: getattr(settings.transport, f)
                                            for f in settings.transport.__dataclass_fields__})
    theta0 = tree.theta(torch.float64)
    lo, hi = tree.spec.lower(), tree.spec.upper()
    b_lo, b_hi = tree.bounds()
    unit = float(max(np.max(b_hi - b_lo), 1e-6))  # the start's size, tree units
    size = tuple(target.shape)
    turns = [0.0] if settings.mode == "profile" else [k * 2 * math.pi / settings.starts for k in range(settings.starts)]

    def run(theta: torch.Tensor, pose: torch.Tensor, steps: int, step0: int):
        """Adam for ``steps`` steps on (theta in units of the start's size, pose); returns the best."""
        z = ((theta - theta0) / unit).clone().requires_grad_(True)
        p = pose.clone().requires_grad_(True)
        scale_px = math.exp(float(pose[2]))
        # per-coordinate steps: parameters in start sizes, translation in pixels, log scale, radians
        rates = torch.tensor([scale_px * unit, scale_px * unit, 1.0, 1.0], dtype=torch.float64)
        best = (math.inf, theta.clone(), pose.clone())
        from ipm.optim.adam import Adam

        opt = Adam([z, p], lr=settings.lr)
        for k in range(steps):
            th = torch.minimum(torch.maximum(theta0 + z * unit, lo), hi)
            d = field_2d(tree, th, p * torch.tensor([1, 1, 1, 0 if settings.mode == "profile" else 1.0],
                                                    dtype=p.dtype), size, settings.mode)
            soft = torch.sigmoid(-d / settings.sigma)
            loss = loss_fn(soft, target)
            value = float(loss.detach())
            if value < best[0]:
                best = (value, th.detach().clone(), p.detach().clone())
            opt.zero_grad()
            loss.backward()
            p.grad = p.grad * rates
            # cosine schedule, as the fit's Adam
            opt.lr = settings.lr * (0.55 + 0.45 * math.cos(math.pi * k / max(steps - 1, 1)))
            opt.step()
            with torch.no_grad():
                z.copy_((torch.minimum(torch.maximum(theta0 + z * unit, lo), hi) - theta0) / unit)
            if progress is not None:
                progress(step0 + k + 1, settings.steps, best[0])
        return best

    short = max(settings.steps // (2 * len(turns)), 1) if len(turns) > 1 else 0
    candidates = []
    for r in turns:
        pose = start_pose(tree, theta0, target, settings.mode, r)
        candidates.append(run(theta0, pose, short, len(candidates) * short) if short else (math.inf, theta0, pose))
    loss, theta, pose = min(candidates, key=lambda c: c[0])
    rest = settings.steps - short * len(turns)
    if rest > 0:
        loss, theta, pose = run(theta, pose, rest, short * len(turns))
    fitted = tree.with_theta(theta)
    with torch.no_grad():
        d = field_2d(fitted, theta, pose, size, settings.mode)
    pred = (d < 0).numpy()
    truth = shape_px.numpy()
    iou = float((pred & truth).sum() / max((pred | truth).sum(), 1))
    pose_out = {"tx": float(pose[0]), "ty": float(pose[1]), "scale": float(math.exp(float(pose[2]))),
                "rotation_deg": 0.0 if settings.mode == "profile" else math.degrees(float(pose[3]))}
    return Fit2DResult(fitted, pose_out, iou, float(loss), settings.steps, time.perf_counter() - t0,
                       settings.mode, pred)


def lifted(result: Fit2DResult, extrude: float | None = None, *, pixels_per_unit: float | None = None,
           center_px: tuple[float, float] | None = None) -> dict:
    """The 3D tree (nested JSON) of a 2D fit: ``profile``: ``revolve`` of the fitted profile; ``shape``:
    ``extrude`` by ``extrude`` (tree units; required). In the tree's units (the image's pixels per unit are
    ``result.pose["scale"]``), or, with ``pixels_per_unit`` (an orthographic view's pixels per world unit)
    and ``center_px`` (the image point (x, y) of the world's origin, y up in the world), scaled and moved
    into that world: the profile's axis at its column, its base at its row, in the plane z = 0."""
    from ipm.sdf.tree import node_to_dict

    child = node_to_dict(result.tree.root)
    if result.mode == "profile":
        solid = {"node": "revolve", "params": {"offset": 0.0}, "children": [child]}
    elif extrude is None:
        raise InputError("2D fit: a shape fit is lifted by extrude with a height; none given")
    else:
        solid = {"node": "extrude", "params": {"height": float(extrude)}, "children": [child]}
    if pixels_per_unit is not None:
        if result.mode != "profile" or center_px is None:
            raise InputError("2D fit: placing in a view's world takes a profile fit and the view's centre")
        pose = result.pose
        solid = {"node": "translate", "params": {"x": (pose["tx"] - center_px[0]) / pixels_per_unit,
                                                 "y": (center_px[1] - pose["ty"]) / pixels_per_unit, "z": 0.0},
                 "children": [{"node": "scale", "params": {"factor": pose["scale"] / pixels_per_unit},
                               "children": [solid]}]}
    return {"tree": solid}


def profile_start(mask: np.ndarray, points: int = 12) -> Tree:
    """A start for a profile fit to the side view ``mask (H, W)``: a closed polygon of ``points`` points (the
    axis, the base, the side in equal steps) as tall, relative to its radius, as the mask is relative to its
    half width (the bounding cylinder)."""
    if points < 4:
        raise InputError(f"2D fit: expected a profile of at least 4 points, got {points}")
    m = np.asarray(mask) > 0.5
    rows, cols = np.nonzero(m.any(1))[0], np.nonzero(m.any(0))[0]
    if len(rows) == 0:
        raise InputError("2D fit: the mask is empty: expected some shape pixels (> 0.5)")
    height = (rows.max() + 1 - rows.min()) / max(0.5 * (cols.max() + 1 - cols.min()), 0.5)
    pts = [(0.0, 0.0)] + [(1.0, height * k / (points - 3)) for k in range(points - 2)] + [(0.0, height)]
    params = {}
    for i, (x, y) in enumerate(pts):
        params[f"x{i}"], params[f"y{i}"] = float(x), float(y)
    from ipm.sdf.tree import tree_from_json

    return tree_from_json({"node": "polygon", "size": points, "params": params}, dim=None)
