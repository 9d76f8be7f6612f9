"""Training data of a proposal network: the generator's own samples, rendered by the exact rasterizer as the
evaluation protocol renders a target from one view, and the augmentations that real masks need.

A sample's continuous values lie between two of the generator's presets (or its defaults), a little beyond either
end, and then each is moved by up to :data:`NOISE` of its range (:data:`DETAIL_NOISE` for detail parameters);
each discrete value is the first preset's or, with probability one half, drawn anew over its range. Presets mixed
keep the shapes objects (a mug between a teacup and a pitcher); parameters drawn one by one make profiles that
zig-zag like no object does. The mesh goes to the protocol's unit bounding sphere, is turned by a random yaw, and
is seen from the protocol's azimuth at a random elevation and distance (:data:`ELEVATIONS`, :data:`DISTANCES`).
Every draw comes from one seeded generator, so a data set is a function
of its seed.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import torch
import torch.nn.functional as F

from ipm.errors import InputError
from ipm.proposals.encode import SIZE, TRAIN_AZIMUTH, encode_mask
from ipm.proposals.net import YAW_BINS

MIX = (-0.15, 1.15)        # where between its two presets a sample lies
NOISE, DETAIL_NOISE = 0.05, 0.02   # of a continuous parameter's range: how far each value then moves
ELEVATIONS = (5.0, 45.0)   # degrees
DISTANCES = (2.6, 4.0)     # the protocol's is 3.2
RENDER = 96                # pixels a side of the renders, before the crop
MAX_TRIES_PER_SAMPLE = 50  # renders drawn per sample asked for (plus 1000) before the generator is given up on


@dataclass(frozen=True)
class Samples:
    """``n`` encoded masks and their answers: ``masks (n, 1, S, S)`` float32, ``continuous (n, c)`` normalized
    to [0, 1], ``discrete (n, d)`` int64 (value less the parameter's lower bound), ``yaw (n,)`` int64 bin of the
    yaw relative to the camera."""

    masks: torch.Tensor
    continuous: torch.Tensor
    discrete: torch.Tensor
    yaw: torch.Tensor

    def __len__(self) -> int:
        return len(self.masks)


def sample_values(gen, rng: np.random.Generator) -> dict:
    """One set of the generator's values between two presets (see the module docstring)."""
    names = [None, *sorted(gen.presets)]
    first = gen.values(names[int(rng.integers(len(names)))])
    second = gen.values(names[int(rng.integers(len(names)))])
    t = float(rng.uniform(*MIX))
    out = {}
    for p in gen.spec.params:
        if p.continuous:
            noise = DETAIL_NOISE if p.detail else NOISE
            v = float(first[p.name]) + t * (float(second[p.name]) - float(first[p.name]))
            out[p.name] = float(np.clip(v + rng.uniform(-noise, noise) * (p.hi - p.lo), p.lo, p.hi))
        elif rng.random() < 0.5:
            out[p.name] = int(rng.integers(int(p.lo), int(p.hi) + 1))
        else:
            out[p.name] = int(first[p.name])
    return out


def render_sample(gen, values: dict, yaw_deg: float, elevation: float, distance: float,
                  size: int = RENDER) -> torch.Tensor | None:
    """The exact mask ``(size, size)`` bool of the generator's shape at ``values``, in the protocol's unit
    bounding sphere, turned by ``yaw_deg`` about +y, seen from the training azimuth; None when the shape is
    empty or leaves the image."""
    from ipm.metrics import unit_sphere_frame
    from ipm.render.camera import orbit_camera
    from ipm.render.raster import rasterize

    mesh = gen.to_mesh(values)
    if mesh.n_faces == 0:
        return None
    V = mesh.verts.detach().double()
    try:
        center, scale = unit_sphere_frame(V.numpy())
    except InputError:
        return None
    a = np.radians(yaw_deg)  # about +y, as the fit's pose turns (ipm.optim.shapes.rot_y)
    R = torch.tensor([[np.cos(a), 0.0, np.sin(a)], [0.0, 1.0, 0.0], [-np.sin(a), 0.0, np.cos(a)]], dtype=torch.float64)
    V = ((V - torch.as_tensor(center)) * scale) @ R.T
    cam = orbit_camera(TRAIN_AZIMUTH, elevation, distance, width=size)
    mask = rasterize(V, mesh.faces, cam).mask
    if not bool(mask.any()) or bool(mask[0].any() | mask[-1].any() | mask[:, 0].any() | mask[:, -1].any()):
        return None
    return mask


def make_samples(gen, n: int, seed: int, progress=None) -> Samples:
    """``n`` samples of ``gen`` drawn from ``seed`` (renders that come out empty or clipped are drawn again, at most
    :data:`MAX_TRIES_PER_SAMPLE` times per sample asked for and 1000 more: then ``InputError``)."""
    rng = np.random.default_rng(seed)
    cont = [p for p in gen.spec.params if p.continuous]
    disc = [p for p in gen.spec.params if not p.continuous]
    masks, cs, ds, ys = [], [], [], []
    tries = 0
    while len(masks) < n:
        tries += 1
        if tries > MAX_TRIES_PER_SAMPLE * n + 1000:
            raise InputError(f"{gen.name}: expected renders of its samples in the image, got {len(masks)} of "
                             f"{tries - 1} tries (the others empty or clipped by the image's border)")
        values = sample_values(gen, rng)
        yaw = float(rng.uniform(0.0, 360.0))
        mask = render_sample(gen, values, yaw, float(rng.uniform(*ELEVATIONS)), float(rng.uniform(*DISTANCES)))
        if mask is None:
            continue
        masks.append(encode_mask(mask, SIZE))
        cs.append([(values[p.name] - p.lo) / (p.hi - p.lo) if p.hi > p.lo else 0.5 for p in cont])
        ds.append([int(values[p.name]) - int(p.lo) for p in disc])
        ys.append(yaw_bin(yaw))
        if progress is not None:
            progress(len(masks), n)
    return Samples(torch.stack(masks), torch.tensor(cs, dtype=torch.float32).reshape(n, len(cont)),
                   torch.tensor(ds, dtype=torch.int64).reshape(n, len(disc)), torch.tensor(ys, dtype=torch.int64))


def yaw_bin(yaw_deg: float) -> int:
    """The bin of a yaw relative to the training camera (bins of 360 / YAW_BINS degrees centred on multiples)."""
    return int(round((yaw_deg % 360.0) / (360.0 / YAW_BINS))) % YAW_BINS


def augment(masks: torch.Tensor, gen: torch.Generator) -> torch.Tensor:
    """What real masks do to a clean one, drawn from ``gen``: the boundary moved and roughened by up to a pixel
    or two (blur, noise, a random threshold), a small occluding rectangle cut out of some, a hole like a
    segmentation's in others, and a crop off by a few pixels. ``masks (B, 1, S, S)`` in [0, 1]."""
    B, _, S, _ = masks.shape
    # a crop off-centre and off-scale by a few per cent
    shift = (torch.rand(B, 2, generator=gen) - 0.5) * 0.08
    zoom = 1.0 + (torch.rand(B, generator=gen) - 0.5) * 0.1
    theta = torch.zeros(B, 2, 3)
    theta[:, 0, 0] = zoom
    theta[:, 1, 1] = zoom
    theta[:, :, 2] = shift
    grid = F.affine_grid(theta, list(masks.shape), align_corners=False)
    m = F.grid_sample(masks, grid, mode="bilinear", padding_mode="zeros", align_corners=False)
    # the boundary: blurred, noised, thresholded anywhere in [0.3, 0.7]
    blurred = F.avg_pool2d(m, 3, stride=1, padding=1, count_include_pad=False)
    noise = (torch.rand(m.shape, generator=gen) - 0.5) * 0.5
    level = 0.3 + 0.4 * torch.rand(B, 1, 1, 1, generator=gen)
    m = ((blurred + noise * (blurred > 0.05) * (blurred < 0.95)) > level).float()
    yy, xx = torch.meshgrid(torch.arange(S, dtype=torch.float32), torch.arange(S, dtype=torch.float32), indexing="ij")
    # an occluder: a rectangle of up to a fifth of the side on a third of the masks
    r = torch.rand(B, 5, generator=gen)
    cx, cy, w, h = r[:, 0] * S, r[:, 1] * S, (0.05 + 0.15 * r[:, 2]) * S, (0.05 + 0.15 * r[:, 3]) * S
    rect = ((xx[None] - cx[:, None, None]).abs() < w[:, None, None] / 2) & \
           ((yy[None] - cy[:, None, None]).abs() < h[:, None, None] / 2) & (r[:, 4] < 1 / 3)[:, None, None]
    # a hole: an ellipse inside the object on a fifth of them
    q = torch.rand(B, 5, generator=gen)
    ex, ey, a, b = (0.3 + 0.4 * q[:, 0]) * S, (0.3 + 0.4 * q[:, 1]) * S, (0.03 + 0.08 * q[:, 2]) * S, \
        (0.03 + 0.08 * q[:, 3]) * S
    hole = (((xx[None] - ex[:, None, None]) / a[:, None, None]) ** 2 + ((yy[None] - ey[:, None, None])
            / b[:, None, None]) ** 2 < 1) & (q[:, 4] < 0.2)[:, None, None]
    return m * (~(rect | hole))[:, None].float()
