"""Line drawings with exact ground truth for ``make table-curves``.

Each drawing is a 256 x 256 raster rendered from known curves: the ink at a pixel is the exact coverage of
a stroke of half-width 1.5 px, ``clip(1.5 + 0.5 - distance, 0, 1)`` with ``distance`` the exact distance
from the pixel's centre to the nearest curve (so ``ink > 0.5`` is the 3 px wide stroke). The ground truth
is the curve network: dense samples of every curve (<= 0.2 px apart), split at junctions so that one
curve runs between two junctions or endpoints (a closed curve without junctions is one curve), the
junction points and the endpoints.

Families (:func:`make_drawings`, deterministic; 22 drawings):

* ``circle``, ``ellipse``: closed parametric curves;
* ``x``: two curves crossing (one junction of degree 4), straight and curved;
* ``t``: a curve ending on another (one junction of degree 3), straight and curved;
* ``arc``, ``s``: open curves (circular and parabolic arcs; a cubic S and a sine wave);
* ``net``: random networks of cubic Bezier curves with junctions of degree 3 and 4 and free ends, seeded;
  a network is redrawn until no two curves cross or come within 8 px of each other away from the
  junctions they share, and curves meet at a junction at >= 35 degrees (so the ground truth is exact);
* ``sdf``: outlines of 2D ``ipm.sdf`` trees (CSG of rects, circles, triangles, rounded rects; the
  ``wind_rose`` preset's 2D shape): the zero level set found by marching squares on an 8x finer grid,
  resampled and moved onto the level set by two Newton steps on the signed distance.

Degraded copies (:func:`degraded`, :func:`make_degraded`; what scans and sketches look like): the same 22
drawings with the same ground truth, the ink redrawn as

1. strokes of a half-width varying smoothly along the curves between :data:`DEGRADE_HALF_WIDTH` = (1.0, 2.5)
   px: ``w(x, y) = 1 + 1.5 f``, ``f`` a sum of :data:`WIDTH_MODES` = 6 random plane waves of wavelengths
   48..128 px, scaled so that its least and greatest values on the drawing's true samples are 0 and 1
   (every drawing spans the whole range; a smooth field of position, so the width is continuous at
   junctions and around closed curves); the ink at a pixel is ``max_s clip(w_s + 0.5 - |p - s|, 0, 1)``
   over the true samples ``s`` (a union of discs, rendered like the clean strokes);
2. blurred by a Gaussian of sigma :data:`BLUR` = 0.7 px;
3. laid on paper with a faint tone: ``1 - (1 - ink) (1 - b)``, ``b`` a smooth field (3 plane waves of
   wavelengths 64..192 px) between 0 and :data:`PAPER` = 0.05;
4. plus i.i.d. Gaussian noise of sigma :data:`NOISE` = 0.1 per pixel, then clipped to [0, 1].

Every random choice comes from ``numpy.random.default_rng([seed, crc32(name)])``: a drawing and a seed
give one image. The clean ink stays with the copy (``Drawing.clean``) for the re-render IoU, which compares
with the clean strokes.
"""

from __future__ import annotations

import functools
import math
import zlib
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from benchmarks.curve_metrics import distance_to_curves, resample

SIZE = 256
HALF_WIDTH = 1.5            # px: strokes are 3 px wide
TRUTH_SPACING = 0.2         # px between ground-truth samples
PRESETS = Path(__file__).resolve().parents[1] / "ipm" / "sdf" / "presets"


@dataclass(frozen=True)
class Drawing:
    """One line drawing and its exact curve network.

    ink: ``(H, W) float`` in [0, 1], 1 = stroke; curves: dense samples ``(n_i, 2)`` per curve (x right,
    y down, pixel centres at +0.5); closed: one flag per curve; junctions ``(j, 2)``, endpoints ``(e, 2)``;
    clean: for a degraded copy, the clean drawing's ink (what the re-render IoU compares with).
    """

    name: str
    family: str
    ink: np.ndarray
    curves: tuple[np.ndarray, ...]
    closed: tuple[bool, ...]
    junctions: np.ndarray
    endpoints: np.ndarray
    clean: np.ndarray | None = None     # a degraded copy's clean ink (the truth's strokes); None: ink is clean

    @property
    def samples(self) -> np.ndarray:
        """All curves' samples ``(n, 2)``."""
        return np.concatenate(self.curves)

    @property
    def truth_ink(self) -> np.ndarray:
        """The clean strokes' ink (``ink`` itself for a clean drawing)."""
        return self.ink if self.clean is None else self.clean


def render_ink(curves, closed, size: tuple[int, int] = (SIZE, SIZE), half_width: float = HALF_WIDTH) -> np.ndarray:
    """Anti-aliased strokes ``(H, W) float`` in [0, 1] from polylines: ``clip(w + 0.5 - distance, 0, 1)``."""
    H, W = size
    yy, xx = np.mgrid[0:H, 0:W]
    centres = np.stack([xx.ravel() + 0.5, yy.ravel() + 0.5], axis=1)
    d = distance_to_curves(centres, curves, closed, upper=half_width + 0.5)
    return np.clip(half_width + 0.5 - d, 0.0, 1.0).reshape(H, W)


def _param(f: Callable[[np.ndarray], np.ndarray], t0: float, t1: float, closed: bool = False) -> np.ndarray:
    """Samples of a parametric curve ``f(t) -> (n, 2)`` on ``[t0, t1]``, uniform in arc length."""
    p = f(np.linspace(t0, t1, 8001))     # chords of <= 0.1 px: off the curve by < 1e-3 px
    return resample(p[:-1] if closed else p, closed, TRUTH_SPACING)


def _bezier(ctrl: np.ndarray) -> Callable[[np.ndarray], np.ndarray]:
    c = np.asarray(ctrl, dtype=np.float64)

    def f(t):
        t = t[:, None]
        return ((1 - t) ** 3 * c[0] + 3 * (1 - t) ** 2 * t * c[1] + 3 * (1 - t) * t ** 2 * c[2] + t ** 3 * c[3])
    return f


def _drawing(name, family, curves, closed, junctions=(), endpoints=()) -> Drawing:
    curves = tuple(np.asarray(c, dtype=np.float64) for c in curves)
    closed = tuple(bool(c) for c in closed)
    return Drawing(name, family, render_ink(curves, closed), curves, closed,
                   np.asarray(junctions, dtype=np.float64).reshape(-1, 2),
                   np.asarray(endpoints, dtype=np.float64).reshape(-1, 2))


# -- closed parametric curves ------------------------------------------------------------------------

def _ellipse(name, family, cx, cy, a, b, angle_deg) -> Drawing:
    c, s = math.cos(math.radians(angle_deg)), math.sin(math.radians(angle_deg))

    def f(t):
        x, y = a * np.cos(t), b * np.sin(t)
        return np.stack([cx + c * x - s * y, cy + s * x + c * y], axis=1)
    return _drawing(name, family, [_param(f, 0.0, 2 * math.pi, closed=True)], [True])


# -- crossings and T-junctions: every branch passes through the junction c at t = 0 ----------------------

def _branch(c, u, bend):
    """The curve ``c + t u + bend t^2 n`` (n: u turned by 90 degrees), through c at t = 0."""
    c, u = np.asarray(c, float), np.asarray(u, float) / np.linalg.norm(u)
    n = np.array([-u[1], u[0]])
    return lambda t: c + t[:, None] * u + bend * (t[:, None] ** 2) * n


def _x(name, c, u, v, bend_u, bend_v, lengths) -> Drawing:
    fu, fv = _branch(c, u, bend_u), _branch(c, v, bend_v)
    curves, ends = [], []
    for f, (a, b) in ((fu, lengths[0]), (fv, lengths[1])):
        curves += [_param(f, 0.0, -a), _param(f, 0.0, b)]
        ends += [f(np.array([-a]))[0], f(np.array([b]))[0]]
    return _drawing(name, "x", curves, [False] * 4, [c], ends)


def _t(name, c, u, bend_u, bar, v, bend_v, stem) -> Drawing:
    fu, fv = _branch(c, u, bend_u), _branch(c, v, bend_v)
    curves = [_param(fu, 0.0, -bar[0]), _param(fu, 0.0, bar[1]), _param(fv, 0.0, stem)]
    ends = [fu(np.array([-bar[0]]))[0], fu(np.array([bar[1]]))[0], fv(np.array([stem]))[0]]
    return _drawing(name, "t", curves, [False] * 3, [c], ends)


def _open(name, family, f, t0, t1) -> Drawing:
    c = _param(f, t0, t1)
    return _drawing(name, family, [c], [False], (), [c[0], c[-1]])


# -- random Bezier networks -----------------------------------------------------------------------------

MARGIN = 16.0
GAP = 8.0            # px: least distance between two curves away from a shared junction
NEAR = 12.0          # px: around a shared junction, curves may approach each other
MIN_ANGLE = 35.0     # degrees between two curves leaving one junction


def _edge(rng, a, b) -> np.ndarray:
    """A cubic Bezier from a to b whose control points sit at a third and two thirds of the chord, pushed
    sideways (so the curve is a graph over its chord and cannot loop)."""
    a, b = np.asarray(a, float), np.asarray(b, float)
    chord = b - a
    n = np.array([-chord[1], chord[0]])
    o1, o2 = rng.uniform(-0.35, 0.35, 2)
    ctrl = [a, a + chord / 3 + o1 * n, a + 2 * chord / 3 + o2 * n, b]
    return _param(_bezier(np.array(ctrl)), 0.0, 1.0)


def _network_ok(nodes, edges, curves) -> bool:
    from scipy.spatial import cKDTree

    lo, hi = MARGIN, SIZE - MARGIN
    if any(((c < lo) | (c > hi)).any() for c in curves):
        return False
    for i in range(len(edges)):
        for j in range(i + 1, len(edges)):
            shared = set(edges[i]) & set(edges[j])
            ci, cj = curves[i], curves[j]
            for s in shared:   # keep only samples away from the junction they share
                ci = ci[np.linalg.norm(ci - nodes[s], axis=1) > NEAR]
                cj = cj[np.linalg.norm(cj - nodes[s], axis=1) > NEAR]
            if len(ci) and len(cj) and cKDTree(cj).query(ci[::4])[0].min() < GAP:     # samples 0.2 px apart
                return False
    for k in range(len(nodes)):    # angles between curves leaving one node
        dirs = []
        for (a, b), c in zip(edges, curves):
            if k in (a, b):
                path = c if a == k else c[::-1]
                step = path[min(len(path) - 1, int(NEAR / TRUTH_SPACING))] - path[0]
                dirs.append(step / np.linalg.norm(step))
        for i in range(len(dirs)):
            for j in range(i + 1, len(dirs)):
                if math.degrees(math.acos(np.clip(dirs[i] @ dirs[j], -1, 1))) < MIN_ANGLE:
                    return False
    return True


def _network(name: str, seed: int) -> Drawing:
    rng = np.random.default_rng(seed)
    for _ in range(1000):
        J = int(rng.integers(2, 4))
        junctions = []
        while len(junctions) < J:
            p = rng.uniform(56, SIZE - 56, 2)
            if all(np.linalg.norm(p - q) > 70 for q in junctions):
                junctions.append(p)
        nodes = list(junctions)
        edges = [(i, i + 1) for i in range(J - 1)]
        if J == 3 and rng.random() < 0.5:
            edges.append((0, 2))
        for j in range(J):
            want = int(rng.integers(3, 5))
            while sum(j in e for e in edges) < want:
                ang, length = rng.uniform(0, 2 * math.pi), rng.uniform(35, 85)
                nodes.append(nodes[j] + length * np.array([math.cos(ang), math.sin(ang)]))
                edges.append((j, len(nodes) - 1))
        curves = [_edge(rng, nodes[a], nodes[b]) for a, b in edges]
        if _network_ok(nodes, edges, curves):
            degree = [sum(k in e for e in edges) for k in range(len(nodes))]
            ends = [nodes[k] for k in range(len(nodes)) if degree[k] == 1]
            return _drawing(name, "net", curves, [False] * len(curves), junctions, ends)
    raise RuntimeError(f"no valid network for seed {seed}")


# -- outlines of 2D SDF trees ------------------------------------------------------------------------------

SDF_SCALE = 100.0      # px per unit: world (X, Y) -> pixel (128 + 100 X, 128 - 100 Y)
SDF_FINE = 8           # marching squares on an 8x finer grid


def _sdf_outline(name: str) -> Drawing:
    """The closed zero-level curves of the 2D node ``SDF_SHAPES[name]()``."""
    import torch
    from skimage.measure import find_contours

    from ipm.sdf import Tree

    tree = Tree(SDF_SHAPES[name]().extrude(1.0))    # on the plane z = 0 an extrusion's zero set is the 2D shape's

    def sdf(xy_px: np.ndarray, grad: bool = False):
        X = torch.as_tensor((xy_px[:, 0] - SIZE / 2) / SDF_SCALE, dtype=torch.float64)
        Y = torch.as_tensor((SIZE / 2 - xy_px[:, 1]) / SDF_SCALE, dtype=torch.float64)
        p = torch.stack([X, Y, torch.zeros_like(X)], dim=1).requires_grad_(grad)
        d = tree.sdf(None, p)
        if not grad:
            return d.detach().numpy() * SDF_SCALE
        (g,) = torch.autograd.grad(d.sum(), p)
        gp = np.stack([g[:, 0].numpy(), -g[:, 1].numpy()], axis=1)     # d/dx_px, d/dy_px (in world units)
        return d.detach().numpy() * SDF_SCALE, gp

    n = SIZE * SDF_FINE
    ticks = (np.arange(n) + 0.5) / SDF_FINE
    gx, gy = np.meshgrid(ticks, ticks)
    with torch.no_grad():
        # the fine grid only near the zero set: elsewhere the pixel-centre value's sign is enough (our
        # nodes' distances never exceed the true ones, so |d| >= 2 px at a centre means no zero in its pixel)
        cy, cx = np.mgrid[0:SIZE, 0:SIZE] + 0.5
        coarse = sdf(np.stack([cx.ravel(), cy.ravel()], axis=1)).reshape(SIZE, SIZE)
        field = np.repeat(np.repeat(coarse, SDF_FINE, axis=0), SDF_FINE, axis=1)
        band = np.abs(field) < 2.0
        field[band] = sdf(np.stack([gx[band], gy[band]], axis=1))
    curves = []
    for c in find_contours(field, 0.0):          # (row, col) in the fine grid
        xy = np.stack([(c[:, 1] + 0.5) / SDF_FINE, (c[:, 0] + 0.5) / SDF_FINE], axis=1)
        closed = np.allclose(c[0], c[-1])
        xy = resample(xy[:-1] if closed else xy, closed, TRUTH_SPACING)
        for _ in range(2):                       # Newton steps onto the level set
            d, g = sdf(xy, grad=True)
            xy = xy - (d / np.maximum((g * g).sum(1), 1e-12))[:, None] * g
        curves.append(xy)
    return _drawing(name, "sdf", curves, [True] * len(curves))


def _rose():
    from ipm.sdf import load_tree

    return load_tree(PRESETS / "wind_rose.json").root.children[0]     # round2d(wind_rose): the 2D shape


def _sdf(build: Callable):
    def make():
        import ipm.sdf as S

        return build(S)
    return make


SDF_SHAPES: dict[str, Callable] = {
    "sdf_rect_circle": _sdf(lambda S: S.rect(1.2, 0.8).translate(-0.2, -0.15) | S.circle(0.45).translate(0.45, 0.3)),
    "sdf_wind_rose": lambda: _rose().scale(1.1).rotate(10.0),
    "sdf_frame_hole": _sdf(lambda S: S.round_rect(1.6, 1.1, 0.25) - S.circle(0.32).translate(-0.3, 0.0)
                           - S.rect(0.4, 0.4).rotate(45.0).translate(0.4, 0.05)),
    "sdf_triangle_circle": _sdf(lambda S: S.triangle(-0.9, -0.8, 0.9, -0.7, 0.0, 0.7)
                                | S.circle(0.33).translate(0.0, 0.7)),
    "sdf_rotated_rects": _sdf(lambda S: S.rect(1.5, 0.35).rotate(25.0) | S.rect(0.35, 1.5).rotate(25.0)),
}


def _recipes() -> dict[str, Callable[[], Drawing]]:
    """Every drawing's name and how to draw it, in the table's order."""
    c = SIZE / 2

    def arc(t):
        return np.stack([c + 85 * np.cos(t), c + 85 * np.sin(t)], 1)

    def parabola(t):
        return np.stack([c + t, 60 + 0.012 * t ** 2], 1)

    def sine(t):
        return np.stack([t, c + 50 * np.sin((t - 24) / 208 * 3 * math.pi)], 1)

    s_ctrl = np.array([[30, 200], [250, 230], [10, 30], [225, 55]])
    recipes = {
        "circle_r80": lambda: _ellipse("circle_r80", "circle", c, c, 80, 80, 0),
        "circle_r40_off": lambda: _ellipse("circle_r40_off", "circle", 90.3, 150.7, 45, 45, 0),
        "ellipse_30deg": lambda: _ellipse("ellipse_30deg", "ellipse", c, c, 100, 55, 30),
        "ellipse_m60deg": lambda: _ellipse("ellipse_m60deg", "ellipse", 140.2, 120.9, 70, 35, -60),
        "x_straight": lambda: _x("x_straight", (128.3, 127.6), (1, 0.35), (0.45, 1), 0, 0, ((90, 100), (95, 85))),
        "x_curved": lambda: _x("x_curved", (125.0, 128.0), (1, -0.2), (0.3, 1), 0.006, -0.008, ((90, 95), (90, 85))),
        "t_straight": lambda: _t("t_straight", (128.3, 90.4), (1, 0), 0, (100, 100), (0, 1), 0, 130),
        "t_curved": lambda: _t("t_curved", (110.0, 100.0), (1, 0.3), -0.005, (80, 105), (-0.3, 1), 0.006, 105),
        "arc_200deg": lambda: _open("arc_200deg", "arc", arc, math.radians(-10), math.radians(190)),
        "arc_parabola": lambda: _open("arc_parabola", "arc", parabola, -100, 100),
        "s_bezier": lambda: _open("s_bezier", "s", _bezier(s_ctrl), 0, 1),
        "s_sine": lambda: _open("s_sine", "s", sine, 24, 232),
    }
    for seed in range(5):
        recipes[f"net_{seed}"] = functools.partial(_network, f"net_{seed}", seed)
    for name in SDF_SHAPES:
        recipes[name] = functools.partial(_sdf_outline, name)
    return recipes


@functools.cache
def drawing(name: str) -> Drawing:
    """One drawing by name (cached; deterministic)."""
    recipes = _recipes()
    if name not in recipes:
        raise ValueError(f"expected a drawing name of {', '.join(recipes)}, got {name!r}")
    return recipes[name]()


def names() -> tuple[str, ...]:
    """Every drawing's name, in the table's order."""
    return tuple(_recipes())


def make_drawings() -> tuple[Drawing, ...]:
    """All 22 drawings, in a fixed order."""
    return tuple(drawing(n) for n in names())


QUICK = ("circle_r80", "x_straight", "net_0", "sdf_rect_circle")


def quick_drawings() -> tuple[Drawing, ...]:
    """Four drawings covering closed, crossing, network and SDF outlines (the ``--quick`` set)."""
    return tuple(drawing(n) for n in QUICK)


# -- degraded copies: what scans and sketches look like ------------------------------------------------------

DEGRADE_HALF_WIDTH = (1.0, 2.5)   # px: least and greatest half-width along the curves
WIDTH_MODES = 6                   # plane waves in the half-width field
WIDTH_WAVELENGTH = (48.0, 128.0)  # px
BLUR = 0.7                        # px: Gaussian sigma
PAPER = 0.05                      # greatest paper tone (ink units)
PAPER_WAVELENGTH = (64.0, 192.0)  # px
NOISE = 0.1                       # sigma of the additive per-pixel Gaussian noise (ink units)


def _waves(rng: np.random.Generator, xy: np.ndarray, modes: int, wavelengths: tuple[float, float]) -> np.ndarray:
    """A sum of ``modes`` plane waves of random direction, wavelength and phase at points ``xy (n, 2)``."""
    ang = rng.uniform(0.0, 2 * math.pi, modes)
    k = 2 * math.pi / rng.uniform(*wavelengths, modes)
    phase = rng.uniform(0.0, 2 * math.pi, modes)
    amp = rng.uniform(0.5, 1.0, modes)
    kv = np.stack([k * np.cos(ang), k * np.sin(ang)], axis=1)
    return (amp * np.cos(xy @ kv.T + phase)).sum(axis=1)


def _unit(v: np.ndarray, ref: np.ndarray) -> np.ndarray:
    """``v`` scaled so that ``ref`` spans [0, 1]."""
    lo, hi = float(ref.min()), float(ref.max())
    return (v - lo) / max(hi - lo, 1e-12)


def variable_width_ink(d: Drawing, half_widths: np.ndarray) -> np.ndarray:
    """Strokes of a half-width given at each true sample (``half_widths (n,)``, aligned with ``d.samples``):
    ``max_s clip(w_s + 0.5 - |p - s|, 0, 1)`` over the samples ``s`` -> ``(H, W)`` in [0, 1]."""
    from scipy.spatial import cKDTree

    H, W = d.ink.shape
    s = d.samples
    reach = float(half_widths.max()) + 0.5
    yy, xx = np.mgrid[0:H, 0:W]
    centres = np.stack([xx.ravel() + 0.5, yy.ravel() + 0.5], axis=1)
    near = np.isfinite(cKDTree(s).query(centres, distance_upper_bound=reach)[0])
    idx = np.nonzero(near)[0]
    pairs = cKDTree(s).sparse_distance_matrix(cKDTree(centres[idx]), reach, output_type="ndarray")
    value = np.clip(half_widths[pairs["i"]] + 0.5 - pairs["v"], 0.0, 1.0)
    out = np.zeros(H * W)
    np.maximum.at(out, idx[pairs["j"]], value)
    return out.reshape(H, W)


def degrade_layers(d: Drawing, seed: int = 0) -> dict[str, np.ndarray]:
    """The degradation of clean drawing ``d`` step by step (see the module's docstring): ``half_widths``
    per true sample, ``strokes`` (variable width), ``blurred``, ``paper`` (the tone ``b``), ``noise_free``
    (blurred strokes on the paper), ``noise`` and ``ink`` = ``clip(noise_free + noise, 0, 1)``."""
    from scipy.ndimage import gaussian_filter

    rng = np.random.default_rng([seed, zlib.crc32(d.name.encode())])
    H, W = d.ink.shape
    s = d.samples
    f = _waves(rng, s, WIDTH_MODES, WIDTH_WAVELENGTH)
    lo, hi = DEGRADE_HALF_WIDTH
    half_widths = lo + (hi - lo) * _unit(f, f)
    strokes = variable_width_ink(d, half_widths)
    blurred = np.clip(gaussian_filter(strokes, BLUR, mode="constant"), 0.0, 1.0)
    yy, xx = np.mgrid[0:H, 0:W]
    grid = np.stack([xx.ravel() + 0.5, yy.ravel() + 0.5], axis=1)
    tone = _waves(rng, grid, 3, PAPER_WAVELENGTH)
    paper = PAPER * _unit(tone, tone).reshape(H, W)
    noise_free = 1.0 - (1.0 - blurred) * (1.0 - paper)
    noise = rng.normal(0.0, NOISE, (H, W))
    return {"half_widths": half_widths, "strokes": strokes, "blurred": blurred, "paper": paper,
            "noise_free": noise_free, "noise": noise, "ink": np.clip(noise_free + noise, 0.0, 1.0)}


def degrade(d: Drawing, seed: int = 0) -> Drawing:
    """A degraded copy of clean drawing ``d``: the same truth, the ink of :func:`degrade_layers`, the clean
    ink kept as ``clean``."""
    if d.clean is not None:
        raise ValueError(f"{d.name} is already degraded")
    ink = degrade_layers(d, seed)["ink"]
    return Drawing(d.name, d.family, ink, d.curves, d.closed, d.junctions, d.endpoints, clean=d.ink)


@functools.cache
def degraded(name: str, seed: int = 0) -> Drawing:
    """The degraded copy of one drawing by name (cached; deterministic per name and seed)."""
    return degrade(drawing(name), seed)


def make_degraded(seed: int = 0) -> tuple[Drawing, ...]:
    """All 22 drawings' degraded copies, in the clean set's order."""
    return tuple(degraded(n, seed) for n in names())


def quick_degraded(seed: int = 0) -> tuple[Drawing, ...]:
    """The ``--quick`` set's degraded copies."""
    return tuple(degraded(n, seed) for n in QUICK)
