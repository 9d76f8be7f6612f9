"""ipm.curves: the bicubic Hermite field against a dense reference and finite differences, and
vectorization of drawings with exact curves (F-measure, IoU, topology)."""

from __future__ import annotations

import numpy as np
import pytest
import torch

from ipm.curves import Curve, Vectorized, VectorizeSettings, from_json, render_strokes, to_json, to_svg, vectorize
from ipm.curves.bezier import fit_beziers, sample_beziers
from ipm.curves.hermite import raster_loss, render_field, sample_cells
from ipm.errors import InputError


def drawing(curves: list[np.ndarray], size: int = 256, r: float = 1.5) -> np.ndarray:
    """Anti-aliased ink (size, size) of strokes of half-width r along densely sampled curves: coverage
    clip(r + 1/2 - d, 0, 1) of a pixel whose centre is d from the curve."""
    from scipy.spatial import cKDTree

    yy, xx = np.mgrid[0:size, 0:size] + 0.5
    d, _ = cKDTree(np.concatenate(curves)).query(np.stack([xx.ravel(), yy.ravel()], 1))
    return np.clip(r + 0.5 - d, 0.0, 1.0).reshape(size, size)


def circle() -> list[np.ndarray]:
    t = np.linspace(0, 2 * np.pi, 4000)
    return [np.stack([128 + 80 * np.cos(t), 128 + 80 * np.sin(t)], 1)]


def tee() -> list[np.ndarray]:
    t = np.linspace(0, 1, 2000)
    return [np.stack([40 + 176 * t, 80 + 0 * t], 1), np.stack([128 + 0 * t, 80 + 130 * t], 1)]


def crossing() -> list[np.ndarray]:
    """Two curves crossing once, at about (177.33, 70.32) (the other close approach, 15 pixels apart
    near (96, 169), is no crossing)."""
    t = np.linspace(30, 226, 4000)
    return [np.stack([t, 128 + 60 * np.sin(t / 40)], 1), np.stack([128 + 50 * np.sin(t / 50), t], 1)]


def open_arc() -> list[np.ndarray]:
    t = np.linspace(40, 216, 4000)
    return [np.stack([t, 128 + 50 * np.sin(t / 30)], 1)]


def curved_tee() -> list[np.ndarray]:
    """A bent bar and a bent stem meeting it at (110, 100) (the benchmark's ``t_curved``: the fit ends
    the stem's zero set a few pixels short of the bar)."""
    u, v = np.array([1.0, 0.3]) / np.hypot(1.0, 0.3), np.array([-0.3, 1.0]) / np.hypot(0.3, 1.0)

    def branch(d, bend, t):
        return np.array([110.0, 100.0]) + t[:, None] * d + bend * t[:, None] ** 2 * np.array([-d[1], d[0]])
    return [branch(u, -0.005, np.linspace(-80, 105, 4000)), branch(v, 0.006, np.linspace(0, 105, 3000))]


def star() -> list[np.ndarray]:
    """A closed four-pointed star outline (sharp convex tips, concave corners of about 100 degrees),
    turned by 20 degrees: like the wind rose, one closed curve with no endpoints and no junctions."""
    a = np.radians(20) + np.arange(8) * np.pi / 4
    rad = np.where(np.arange(8) % 2 == 0, 95.0, 38.0)
    corners = np.stack([128 + rad * np.cos(a), 128 + rad * np.sin(a)], 1)
    corners = np.concatenate([corners, corners[:1]])
    t = np.linspace(0, 1, 600)[:-1, None]
    return [np.concatenate([a * (1 - t) + b * t for a, b in zip(corners[:-1], corners[1:])] + [corners[:1]])]


def rectangle() -> list[np.ndarray]:
    """A closed rectangle outline (160 x 100) turned by 10 degrees: four right-angled corners."""
    a = np.radians(10)
    turn = np.array([[np.cos(a), -np.sin(a)], [np.sin(a), np.cos(a)]])
    corners = np.array([[-80, -50], [80, -50], [80, 50], [-80, 50], [-80, -50]]) @ turn.T + 128
    t = np.linspace(0, 1, 1000)[:-1, None]
    return [np.concatenate([a * (1 - t) + b * t for a, b in zip(corners[:-1], corners[1:])] + [corners[:1]])]


def iou(v: Vectorized, ink: np.ndarray) -> float:
    drawn, mask = render_strokes(v, v.size, v.width), ink > 0.5
    return (drawn & mask).sum() / (drawn | mask).sum()


def f_measure(v: Vectorized, truth: list[np.ndarray], thr: float) -> float:
    from scipy.spatial import cKDTree

    out = np.concatenate([sample_beziers(c.beziers, 0.5) for c in v.curves])
    true = np.concatenate(truth)
    p = np.mean(cKDTree(true).query(out)[0] <= thr)
    r = np.mean(cKDTree(out).query(true)[0] <= thr)
    return 2 * p * r / (p + r)


def _reference(data: np.ndarray, u: float, v: float) -> float:
    """The bicubic Hermite patch by its textbook definition: sum over corners of value, slopes and twist
    times products of the 1D Hermite basis functions."""
    h = [lambda t: 2 * t**3 - 3 * t**2 + 1, lambda t: -2 * t**3 + 3 * t**2]  # value at 0, at 1
    g = [lambda t: t**3 - 2 * t**2 + t, lambda t: t**3 - t**2]  # slope at 0, at 1
    s = 0.0
    for j in range(2):
        for i in range(2):
            p, pu, pv, puv = data[j, i]
            s += p * h[i](u) * h[j](v) + pu * g[i](u) * h[j](v) + pv * h[i](u) * g[j](v) + puv * g[i](u) * g[j](v)
    return s


def test_patch_matches_the_reference_and_interpolates_corner_data(rng):
    data = rng.normal(size=(1, 1, 2, 2, 4))
    t = torch.tensor([0.0, 0.3, 0.7, 1.0], dtype=torch.float64)
    p = sample_cells(torch.tensor(data), t)[0, 0].numpy()
    for a, v in enumerate(t.tolist()):
        for b, u in enumerate(t.tolist()):
            assert p[a, b] == pytest.approx(_reference(data[0, 0], u, v), abs=1e-12)
    ends = torch.tensor([0.0, 1.0], dtype=torch.float64)
    d = torch.tensor(data)
    for q, (du, dv) in enumerate([(0, 0), (1, 0), (0, 1), (1, 1)]):
        corner = sample_cells(d, ends, du=du, dv=dv)[0, 0].numpy()  # [v, u] = corner (j, i)
        np.testing.assert_allclose(corner, data[0, 0, :, :, q], atol=1e-12)


def test_cells_sharing_corner_data_are_c1_across_their_edge(rng):
    data = rng.normal(size=(1, 2, 2, 2, 4))
    data[0, 1, :, 0] = data[0, 0, :, 1]  # the right cell's left corners are the left cell's right ones
    d = torch.tensor(data)
    t = torch.linspace(0, 1, 9, dtype=torch.float64)
    for du, dv in [(0, 0), (1, 0), (0, 1)]:
        left = sample_cells(d, t, du=du, dv=dv)[0, 0, :, -1]
        right = sample_cells(d, t, du=du, dv=dv)[0, 1, :, 0]
        np.testing.assert_allclose(left.numpy(), right.numpy(), atol=1e-12)
    data[0, 1, 0, 0, 1] += 0.5  # a different slope at one shared corner: the u-derivatives now differ
    d = torch.tensor(data)
    assert not np.allclose(sample_cells(d, t, du=1)[0, 0, :, -1], sample_cells(d, t, du=1)[0, 1, :, 0])


def test_field_and_raster_loss_gradcheck(rng):
    data = torch.tensor(rng.normal(size=(2, 3, 2, 2, 4)), requires_grad=True)
    assert torch.autograd.gradcheck(lambda d: render_field(d, 4, (7, 10)), (data,))
    ink = torch.tensor(rng.uniform(size=(7, 10)))
    assert torch.autograd.gradcheck(lambda d: raster_loss(d, ink, 4, 1.2), (data,))


def test_bezier_fit_stays_within_tolerance():
    t = np.linspace(0, 1.5 * np.pi, 300)
    pts = np.stack([50 * np.cos(t), 30 * np.sin(2 * t)], 1)
    bez = fit_beziers(pts, 0.2)
    from scipy.spatial import cKDTree

    assert cKDTree(sample_beziers(bez, 0.05)).query(pts)[0].max() < 0.2 + 0.05
    np.testing.assert_allclose(bez[0, 0], pts[0]) and np.testing.assert_allclose(bez[-1, 3], pts[-1])


@pytest.fixture(scope="module")
def circle_result() -> tuple[Vectorized, np.ndarray]:
    ink = drawing(circle())
    return vectorize(ink, VectorizeSettings(steps=150)), ink


def test_a_circle_is_one_closed_curve(circle_result):
    v, ink = circle_result
    assert len(v.curves) == 1 and v.curves[0].closed
    assert len(v.junctions) == 0 and len(v.endpoints) == 0
    assert f_measure(v, circle(), 0.01 * 256 * np.sqrt(2)) >= 0.95
    drawn, mask = render_strokes(v, v.size, v.width), ink > 0.5
    assert (drawn & mask).sum() / (drawn | mask).sum() >= 0.9


def test_a_t_junction_has_one_junction_and_three_endpoints():
    v = vectorize(drawing(tee()), VectorizeSettings(steps=150))
    assert len(v.junctions) == 1 and len(v.endpoints) == 3
    np.testing.assert_allclose(v.junctions[0], [128, 80], atol=2.0)
    ends = sorted(map(tuple, np.round(v.endpoints)))
    for got, want in zip(ends, sorted([(40, 80), (216, 80), (128, 210)])):
        assert np.hypot(got[0] - want[0], got[1] - want[1]) < 4.0
    assert f_measure(v, tee(), 0.01 * 256 * np.sqrt(2)) >= 0.95


def test_an_x_crossing_is_one_junction_between_two_curves_that_run_straight_through():
    truth = crossing()
    ink = drawing(truth)
    v = vectorize(ink, VectorizeSettings(steps=150))
    assert len(v.junctions) == 1 and len(v.endpoints) == 4 and len(v.curves) == 2
    np.testing.assert_allclose(v.junctions[0], [177.33, 70.32], atol=2.0)
    ends = np.array([c[k] for c in truth for k in (0, -1)])
    assert all(np.min(np.linalg.norm(ends - e, axis=1)) < 2.0 for e in v.endpoints)
    for c in v.curves:  # each curve is one of the strokes, end to end (not two halves joined at the crossing)
        assert min(np.linalg.norm(t[ends] - c.points[[0, -1]], axis=1).sum()
                   for t in truth for ends in ([0, -1], [-1, 0])) < 4.0
    assert f_measure(v, truth, 0.01 * 256 * np.sqrt(2)) >= 0.95 and iou(v, ink) >= 0.9


def test_a_curved_t_whose_stem_the_fit_ends_short_still_meets_the_bar():
    truth = curved_tee()
    ink = drawing(truth)
    v = vectorize(ink, VectorizeSettings(steps=150))
    assert len(v.junctions) == 1 and len(v.endpoints) == 3
    np.testing.assert_allclose(v.junctions[0], [110, 100], atol=2.0)
    assert f_measure(v, truth, 0.01 * 256 * np.sqrt(2)) >= 0.95 and iou(v, ink) >= 0.9


@pytest.mark.parametrize("shape", [rectangle, star])
def test_an_outline_with_sharp_corners_is_one_closed_curve(shape):
    truth = shape()
    ink = drawing(truth)
    v = vectorize(ink, VectorizeSettings(steps=150))
    assert len(v.curves) == 1 and v.curves[0].closed
    assert len(v.junctions) == 0 and len(v.endpoints) == 0
    assert f_measure(v, truth, 0.01 * 256 * np.sqrt(2)) >= 0.95 and iou(v, ink) >= 0.85


def test_an_open_arc_is_one_curve_with_its_ends_where_the_centreline_ends():
    truth = open_arc()
    ink = drawing(truth)
    v = vectorize(ink, VectorizeSettings(steps=150))
    assert len(v.curves) == 1 and not v.curves[0].closed and len(v.junctions) == 0 and len(v.endpoints) == 2
    ends = truth[0][[0, -1]]
    for e in v.endpoints:  # trimmed to the centreline's end, not the round cap's (r = 1.5 further)
        assert np.min(np.linalg.norm(ends - e, axis=1)) < 1.0
    assert f_measure(v, truth, 0.01 * 256 * np.sqrt(2)) >= 0.95 and iou(v, ink) >= 0.9


def test_same_seed_same_result():
    ink = drawing(tee())
    a, b = (vectorize(ink, VectorizeSettings(steps=20)) for _ in range(2))
    assert len(a.curves) == len(b.curves) and a.loss == b.loss
    for ca, cb in zip(a.curves, b.curves):
        np.testing.assert_array_equal(ca.beziers, cb.beziers)


def test_json_round_trip_and_svg(circle_result):
    v, _ = circle_result
    w = from_json(to_json(v))
    assert w.size == v.size and w.width == pytest.approx(v.width) and len(w.curves) == len(v.curves)
    np.testing.assert_allclose(w.curves[0].beziers, v.curves[0].beziers, atol=1e-4)
    assert w.curves[0].closed
    svg = to_svg(v)
    assert svg.startswith("<svg") and svg.count("<path") == 1 and " C" in svg
    with pytest.raises(InputError, match="format"):
        from_json({"format": "other"})


def test_render_strokes_draws_a_band_of_the_half_width():
    seg = np.array([[[10.0, 20.5], [20.0, 20.5], [30.0, 20.5], [40.0, 20.5]]])
    # the curve is sampled every 0.2 pixel: distances are up to 0.1 pixel long, so 2.2 draws rows 18.5..22.5
    img = render_strokes([Curve(points=seg[0], closed=False, beziers=seg)], (40, 50), 2.2)
    assert img[:, 25].sum() == 5 and img[20, 25] and not img[20, 45]


@pytest.mark.parametrize("kw, word", [({"cell": 1}, "cell"), ({"cell": 2.5}, "cell"), ({"width": -1.0}, "width"),
                                      ({"steps": -3}, "steps"), ({"lr": float("nan")}, "lr"),
                                      ({"bezier_tol": 0.0}, "bezier_tol"), ({"seed": -1}, "seed")])
def test_bad_settings_are_refused_in_one_line(kw, word):
    with pytest.raises(InputError) as e:
        VectorizeSettings(**kw).check()
    assert word in str(e.value) and "\n" not in str(e.value)


@pytest.mark.parametrize("ink, word", [(np.zeros((0, 5)), "pixels"), (np.zeros((32, 32)), "nothing"),
                                       (np.ones((32, 32)), "nothing"), (np.zeros((4, 40)), "cell"),
                                       (np.full((20, 20), 2.0), "[0, 1]")])
def test_bad_ink_is_refused(ink, word):
    with pytest.raises(InputError, match=word.replace("[", r"\[").replace("]", r"\]")):
        vectorize(ink)


def test_clean_ink_leaves_a_clean_drawing_as_it_is():
    from ipm.curves.clean import clean_ink

    ink = drawing(tee())
    c = clean_ink(ink)
    assert not c.cleaned and c.ink is ink
    np.testing.assert_array_equal(c.mask, ink > 0.5)


def test_clean_ink_reads_the_noise_and_paper_and_gives_back_the_strokes(rng):
    from ipm.curves.clean import clean_ink, paper_and_noise

    ink = drawing(crossing())
    yy = np.mgrid[0:256, 0:256][0] / 255.0
    paper = 0.04 * yy                                    # a tone rising down the sheet
    noisy = np.clip(ink + paper * (1 - ink) + rng.normal(0.0, 0.1, ink.shape), 0.0, 1.0)
    level, sigma = paper_and_noise(noisy)
    assert 0.07 < sigma < 0.13                           # clipped at 0 below the paper: read off the upper side
    assert abs(float(np.median(level)) - 0.02) < 0.03
    c = clean_ink(noisy)
    truth = ink > 0.5
    assert c.cleaned and 0.0 <= float(c.ink.min()) and float(c.ink.max()) <= 1.0
    assert (c.mask & truth).sum() / (c.mask | truth).sum() > 0.8
    assert float(np.abs(c.ink[~c.mask]).mean()) < 0.2 * float(np.abs(noisy[~truth]).mean())  # paper left clean


def test_a_noisy_scan_vectorizes_like_the_clean_drawing(rng):
    truth = curved_tee()
    ink = drawing(truth)
    noisy = np.clip(ink + 0.03 + rng.normal(0.0, 0.1, ink.shape), 0.0, 1.0)
    v = vectorize(noisy, VectorizeSettings(steps=150))
    assert len(v.junctions) == 1 and len(v.endpoints) == 3
    np.testing.assert_allclose(v.junctions[0], [110, 100], atol=2.0)
    assert f_measure(v, truth, 0.01 * 256 * np.sqrt(2)) >= 0.95 and iou(v, ink) >= 0.9  # the clean strokes
