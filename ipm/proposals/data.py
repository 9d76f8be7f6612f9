"""Training data of a proposal network: the generator's own samples, rendered by the exact rasterizer as the
evaluation protocol renders a target from one view, and the augmentations that real masks need.

A sample's continuous values lie between two of the generator's presets (or its defaults), a little beyond either
end, and then each is moved by up to :data:`NOISE` of its range (:data:`DETAIL_NOISE` for detail parameters);
each discrete value is the first preset's or, with probability one half, drawn anew over its range. Presets mixed
keep the shapes objects (a mug between a teacup and a pitcher); parameters drawn one by one make profiles that
zig-zag like no object does. The mesh goes to the protocol's unit bounding sphere, is turned by a random yaw, and
is seen from the protocol's azimuth at a random elevation and distance (:data:`ELEVATIONS`, :data:`DISTANCES`).
A data set is drawn in chunks of :data:`CHUNK` samples, each from a generator seeded by the seed and the chunk's
index, so it is a function of its seed, whether one process draws it or several side by side.
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
CHUNK = 250                # samples a chunk: what one worker draws from the seed and the chunk's index


@dataclass(frozen=True)
class Samples:
    """``n`` encoded masks and their answers: ``masks (n, 1, S, S)`` uint8 (255 inside; a quarter of float32's
    memory, a data set of 45000 takes 184 MB), ``continuous (n, c)`` normalized to [0, 1], ``discrete (n, d)`` int64
    (value less the parameter's lower bound), ``yaw (n,)`` int64 bin of the yaw relative to the camera."""

    masks: torch.Tensor
    continuous: torch.Tensor
    discrete: torch.Tensor
    yaw: torch.Tensor

    def __len__(self) -> int:
        return len(self.masks)

    def inputs(self, idx: torch.Tensor | None = None) -> torch.Tensor:
        """The masks (those at ``idx``) as the network reads them: float32 in [0, 1]."""
        m = self.masks if idx is None else self.masks[idx]
        return m.to(torch.float32) / 255.0 if m.dtype == torch.uint8 else m


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


def make_samples(gen, n: int, seed: int, progress=None, workers: int = 1) -> Samples:
    """``n`` samples of ``gen`` drawn from ``seed``, in chunks of :data:`CHUNK`: chunk ``c`` draws from the seed and
    ``c`` alone, so the data set is the same whether ``workers`` processes draw the chunks side by side or one does
    (each on one torch thread). Renders that come out empty or clipped are drawn again, at most
    :data:`MAX_TRIES_PER_SAMPLE` times per sample asked for and 1000 more per chunk: then ``InputError``.
    ``progress(done, n)`` as chunks finish."""
    sizes = [min(CHUNK, n - start) for start in range(0, n, CHUNK)]
    parts: list = [None] * len(sizes)
    done = 0
    for c, part in _chunks(gen, seed, sizes, workers):
        parts[c] = part
        done += sizes[c]
        if progress is not None:
            progress(done, n)
    masks, cs, ds, ys = (torch.cat([part[i] for part in parts]) for i in range(4))
    return Samples(masks, cs, ds, ys)


def _chunks(gen, seed: int, sizes: list[int], workers: int):
    """``(c, chunk)`` for every chunk, as they finish (in order with one worker)."""
    if workers <= 1 or len(sizes) == 1:
        for c, m in enumerate(sizes):
            yield c, _chunk(gen, seed, c, m)
        return
    from concurrent.futures import as_completed

    from ipm.threads import process_pool

    with process_pool(workers) as pool:
        futures = {pool.submit(_chunk, gen, seed, c, m): c for c, m in enumerate(sizes)}
        try:
            for fut in as_completed(futures):
                yield futures[fut], fut.result()
        finally:  # on an error or Ctrl-C, chunks not yet started are dropped instead of waited for
            pool.shutdown(wait=True, cancel_futures=True)


def _chunk(gen, seed: int, c: int, m: int) -> tuple[torch.Tensor, ...]:
    """Chunk ``c`` of the data set of ``seed``: ``m`` samples as ``(masks, continuous, discrete, yaw)``."""
    threads = torch.get_num_threads()
    torch.set_num_threads(1)
    try:
        return _draw(gen, np.random.default_rng([seed, c]), m)
    finally:
        torch.set_num_threads(threads)


def _draw(gen, rng: np.random.Generator, m: int) -> tuple[torch.Tensor, ...]:
    cont = [p for p in gen.spec.params if p.continuous]
    disc = [p for p in gen.spec.params if not p.continuous]
    masks, cs, ds, ys = [], [], [], []
    tries = 0
    while len(masks) < m:
        tries += 1
        if tries > MAX_TRIES_PER_SAMPLE * m + 1000:
            raise InputError(f"{gen.name}: expected renders of its samples in the image, got {len(masks)} of "
                             f"{tries - 1} tries (the others empty or clipped by the image's border)")
        values = sample_values(gen, rng)
        yaw = float(rng.uniform(0.0, 360.0))
        mask = render_sample(gen, values, yaw, float(rng.uniform(*ELEVATIONS)), float(rng.uniform(*DISTANCES)))
        if mask is None:
            continue
        masks.append((encode_mask(mask, SIZE) * 255.0).round().to(torch.uint8))
        cs.append([(values[p.name] - p.lo) / (p.hi - p.lo) if p.hi > p.lo else 0.5 for p in cont])
        ds.append([int(values[p.name]) - int(p.lo) for p in disc])
        ys.append(yaw_bin(yaw))
    return (torch.stack(masks), torch.tensor(cs, dtype=torch.float32).reshape(m, len(cont)),
            torch.tensor(ds, dtype=torch.int64).reshape(m, len(disc)), torch.tensor(ys, dtype=torch.int64))


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
