"""The vectorization benchmark (``make table-curves``): its metrics on exact cases, its drawings' ground
truth against their ink, the degraded copies (deterministic, truth kept on the ink, the documented noise),
the two baselines on a circle, and a ``--quick`` run writing its tables."""

from __future__ import annotations

import math

import numpy as np
import pytest

from benchmarks.curve_baselines import potrace_outline, skeleton_trace
from benchmarks.curve_metrics import (
    Traced,
    distance_to_curves,
    fill_mask,
    iou,
    match_points,
    resample,
    score,
    stroke_mask,
)
from benchmarks.drawings import (
    BLUR,
    DEGRADE_HALF_WIDTH,
    HALF_WIDTH,
    NOISE,
    PAPER,
    SIZE,
    degrade,
    degrade_layers,
    degraded,
    drawing,
    make_degraded,
    make_drawings,
    names,
)

INK = np.zeros((256, 256))
DIAG = math.hypot(256, 256)


def _line(y: float) -> np.ndarray:
    return resample(np.array([[20.0, y], [220.0, y]]), False, 0.2)


def _circle(r: float, c=(128.0, 128.0), n: int = 4000) -> np.ndarray:
    t = np.linspace(0, 2 * math.pi, n, endpoint=False)
    return np.stack([c[0] + r * np.cos(t), c[1] + r * np.sin(t)], axis=1)


# -- metrics -------------------------------------------------------------------------------------------------

def test_resample_spacing_and_ends():
    p = np.array([[0.0, 0.0], [10.0, 0.0], [10.0, 7.3]])
    q = resample(p, False)
    assert np.allclose(q[0], p[0]) and np.allclose(q[-1], p[-1])
    assert np.linalg.norm(np.diff(q, axis=0), axis=1).max() <= 0.25 + 1e-12
    c = resample(_circle(30.0, n=50), True)
    gaps = np.linalg.norm(np.diff(np.concatenate([c, c[:1]]), axis=0), axis=1)
    assert gaps.max() <= 0.25 + 1e-12 and not np.allclose(c[0], c[-1])


def test_distance_to_curves_matches_brute_force():
    rng = np.random.default_rng(3)
    curves = [rng.uniform(0, 50, (7, 2)), rng.uniform(0, 50, (5, 2)), rng.uniform(0, 50, (1, 2))]
    closed = [False, True, False]
    q = rng.uniform(-10, 60, (300, 2))
    segs = []
    for c, cl in zip(curves, closed):
        p = np.concatenate([c, c[:1]]) if cl else c
        segs += [(p[i], p[i + 1]) for i in range(len(p) - 1)] or [(p[0], p[0])]
    ref = np.full(len(q), np.inf)
    for a, b in segs:
        ab = b - a
        t = np.clip(((q - a) @ ab) / max(ab @ ab, 1e-300), 0, 1)
        ref = np.minimum(ref, np.linalg.norm(q - (a + t[:, None] * ab), axis=1))
    assert np.allclose(distance_to_curves(q, curves, closed), ref, atol=1e-9)
    far = distance_to_curves(q, curves, closed, upper=2.0)
    assert np.all(np.isinf(far[ref > 2.0 + 1e-9])) and np.allclose(far[ref <= 2.0], ref[ref <= 2.0])


def test_a_curve_against_itself_scores_perfectly():
    truth = [_line(100.0), _circle(50.0)]
    r = score(Traced(tuple(truth), (False, True)), truth, (False, True), np.zeros((0, 2)), np.zeros((0, 2)), INK)
    assert r["chamfer_px"] < 1e-9
    assert all(r[k] == 1.0 for k in ("f@0.25%", "f@0.5%", "f@1%", "f@2%"))
    assert r["curves_pred"] == r["curves_true"] == 2


def test_a_shifted_copy_has_the_shift_as_chamfer():
    r = score(Traced((_line(102.0),), (False,)), [_line(100.0)], [False], np.zeros((0, 2)), np.zeros((0, 2)), INK)
    assert r["chamfer_px"] == pytest.approx(2.0, abs=1e-9)
    assert r["chamfer_diag"] == pytest.approx(2.0 / DIAG)
    assert r["f@0.5%"] == 0.0 and r["f@1%"] == 1.0              # 1.81 px < 2 px < 3.62 px
    # concentric circles: every distance is the difference of radii (up to the chords' sagitta)
    r = score(Traced((_circle(41.0),), (True,)), [resample(_circle(40.0), True, 0.2)], [True],
              np.zeros((0, 2)), np.zeros((0, 2)), INK)
    assert r["chamfer_px"] == pytest.approx(1.0, abs=1e-3)


def test_half_a_curve_has_half_the_recall():
    truth = _line(100.0)
    half = truth[truth[:, 0] <= 120.0]
    r = score(Traced((half,), (False,)), [truth], [False], np.zeros((0, 2)), np.zeros((0, 2)), INK)
    assert r["p@1%"] == 1.0 and r["r@1%"] == pytest.approx(0.5 + 3.62 / 200, abs=0.01)


def test_an_empty_prediction_scores_worst():
    r = score(Traced((), ()), [_line(100.0)], [False], np.zeros((0, 2)), np.array([[20.0, 100.0]]), INK)
    assert r["f@1%"] == 0.0 and r["chamfer_px"] == pytest.approx(DIAG)
    assert r["endpoint_r"] == 0.0 and math.isnan(r["endpoint_p"]) and math.isnan(r["junction_r"])


def test_point_matching_is_one_to_one():
    true = np.array([[0.0, 0.0], [10.0, 0.0]])
    # p0 is near both, p1 only near the first: a greedy nearest match would pair p0 with the first and
    # leave p1 out; the assignment pairs both
    pred = np.array([[3.0, 0.0], [-4.0, 0.0]])
    assert match_points(pred, true, radius=7.5) == 2
    assert match_points(np.array([[0.5, 0.0], [-0.5, 0.0]]), true[:1], radius=5) == 1     # two on one
    assert match_points(pred, true, radius=1.0) == 0
    assert match_points(np.zeros((0, 2)), true, radius=5) == 0
    r = score(Traced((_line(100.0),), (False,), junctions=np.array([[60.0, 101.0], [61.0, 100.0]])),
              [_line(100.0)], [False], np.array([[60.0, 100.0]]), np.zeros((0, 2)), INK)
    assert (r["junction_tp"], r["junction_p"], r["junction_r"]) == (1, 0.5, 1.0)


def test_masks_and_iou():
    square = np.array([[10.0, 10.0], [50.0, 10.0], [50.0, 50.0], [10.0, 50.0]])
    hole = np.array([[20.0, 20.0], [30.0, 20.0], [30.0, 30.0], [20.0, 30.0]])
    m = fill_mask([square, hole], (64, 64))
    assert m.sum() == 40 * 40 - 10 * 10 and not m[25, 25] and m[15, 15]
    s = stroke_mask([np.array([[10.0, 20.5], [40.0, 20.5]])], [False], (64, 64), 1.0)
    assert s[19:22, 10:40].all() and s.sum() == 3 * 30 + 2     # rows 19.5..21.5, and one pixel of each round cap
    assert iou(m, m) == 1.0 and iou(m, ~m) == 0.0 and iou(np.zeros(3, bool), np.zeros(3, bool)) == 1.0


# -- drawings ------------------------------------------------------------------------------------------------

def test_drawings_are_many_and_deterministic():
    all_names = names()
    assert len(all_names) >= 20 and len(set(all_names)) == len(all_names)
    families = {n.split("_")[0] for n in all_names}
    assert {"circle", "ellipse", "x", "t", "arc", "s", "net", "sdf"} <= families
    from benchmarks.drawings import _network

    a, b = drawing("net_2"), _network("net_2", 2)
    assert np.array_equal(a.ink, b.ink) and all(np.array_equal(p, q) for p, q in zip(a.curves, b.curves))


def test_ground_truth_lies_on_the_ink():
    for d in make_drawings():
        assert d.ink.shape == (SIZE, SIZE) and 0.0 <= d.ink.min() and d.ink.max() <= 1.0
        for c, cl in zip(d.curves, d.closed):
            gaps = np.linalg.norm(np.diff(np.concatenate([c, c[:1]]) if cl else c, axis=0), axis=1)
            assert gaps.max() <= 0.25, d.name
        s = d.samples
        ij = np.clip(np.floor(s).astype(int), 0, SIZE - 1)
        assert (d.ink[ij[:, 1], ij[:, 0]] > 0.5).all(), d.name        # the pixel under every true sample
        nodes = np.concatenate([d.junctions, d.endpoints])
        if len(nodes):
            assert distance_to_curves(nodes, d.curves, d.closed).max() < 0.3, d.name
        # the ink is exactly the strokes of the true curves: re-rendered at the true width they agree
        assert iou(stroke_mask(d.curves, d.closed, d.ink.shape, HALF_WIDTH), d.ink > 0.5) > 0.995, d.name
    net = [d for d in make_drawings() if d.family == "net"]
    assert all(len(d.junctions) >= 1 and len(d.endpoints) >= 3 for d in net)


# -- degraded copies ------------------------------------------------------------------------------------------

def _under(d, values: np.ndarray) -> np.ndarray:
    """``values (H, W)`` at the pixel under every true sample of ``d``."""
    ij = np.clip(np.floor(d.samples).astype(int), 0, SIZE - 1)
    return values[ij[:, 1], ij[:, 0]]


def test_degraded_drawings_are_deterministic_per_seed():
    a, b = degrade(drawing("net_2"), seed=0), degraded("net_2", seed=0)
    assert np.array_equal(a.ink, b.ink)
    c, e = degrade(drawing("net_2"), seed=1), degrade(drawing("x_curved"), seed=0)
    assert not np.allclose(a.ink, c.ink) and not np.allclose(a.ink[:64, :64], e.ink[:64, :64])
    assert a.name == "net_2" and np.array_equal(a.clean, drawing("net_2").ink)
    with pytest.raises(ValueError, match="already degraded"):
        degrade(a)


def test_degraded_drawings_keep_their_truth_on_the_ink():
    clean = make_drawings()
    for c, d in zip(clean, make_degraded()):
        assert d.name == c.name and d.ink.shape == (SIZE, SIZE) and 0.0 <= d.ink.min() and d.ink.max() <= 1.0
        # the truth is the clean drawing's, untouched
        assert all(np.array_equal(p, q) for p, q in zip(d.curves, c.curves)) and d.closed == c.closed
        assert np.array_equal(d.junctions, c.junctions) and np.array_equal(d.endpoints, c.endpoints)
        assert np.array_equal(d.truth_ink, c.ink) and (_under(d, d.truth_ink) > 0.5).all(), d.name
        layers = degrade_layers(c, seed=0)
        assert np.array_equal(layers["ink"], d.ink)
        # before the noise, every true sample's pixel is ink (> 0.5; measured: >= 0.66 on all 22), and so
        # is nearly every one after it (a 0.1 sigma noise pulls a few of the thinnest strokes' pixels under)
        assert (_under(d, layers["noise_free"]) > 0.6).all(), d.name
        assert (_under(d, d.ink) > 0.5).mean() > 0.97, d.name
        lo, hi = DEGRADE_HALF_WIDTH
        assert layers["half_widths"].min() == pytest.approx(lo) and layers["half_widths"].max() == pytest.approx(hi)
        assert 0.0 <= layers["paper"].min() and layers["paper"].max() <= PAPER + 1e-12


def test_degraded_noise_is_what_the_docstring_says():
    import benchmarks.drawings as D

    for value, text in ((NOISE, "sigma :data:`NOISE` = 0.1"), (BLUR, "sigma :data:`BLUR` = 0.7"),
                        (PAPER, ":data:`PAPER` = 0.05")):
        assert text in D.__doc__ and f"{value:g}" in text
    assert f"{DEGRADE_HALF_WIDTH}".replace(" ", "") in D.__doc__.replace(" ", "").replace("\n", "")
    c = drawing("s_sine")
    layers = degrade_layers(c, seed=0)
    assert np.array_equal(layers["ink"], np.clip(layers["noise_free"] + layers["noise"], 0.0, 1.0))
    assert layers["noise"].std() == pytest.approx(NOISE, rel=0.02) and abs(layers["noise"].mean()) < 0.002
    # measured on the clipped image itself, where clipping at 0 cannot bias it: on the paper away from the
    # strokes, the share of pixels at least one (two) sigma above their noise-free value is the normal's
    y, v = layers["ink"], layers["noise_free"]
    paper = layers["blurred"] == 0.0
    assert paper.mean() > 0.8
    excess = (y - v)[paper]
    assert (excess >= NOISE).mean() == pytest.approx(0.1587, abs=0.006)
    assert (excess >= 2 * NOISE).mean() == pytest.approx(0.0228, abs=0.003)
    # the width varies smoothly along the curve: adjacent samples (0.2 px apart) differ by < 0.05 px
    w = layers["half_widths"]
    assert np.abs(np.diff(w)).max() < 0.05


# -- baselines -----------------------------------------------------------------------------------------------

def _score(d, t):
    return score(t, d.curves, d.closed, d.junctions, d.endpoints, d.ink)


def test_baselines_on_a_circle():
    d = drawing("circle_r80")
    sk = _score(d, skeleton_trace(d.ink))
    # measured: F@1% 1.000, Chamfer 0.19 px, IoU 0.91
    assert sk["f@1%"] > 0.99 and sk["chamfer_px"] < 0.4 and sk["curves_pred"] == 1 and sk["iou"] > 0.85
    po = _score(d, potrace_outline(d.ink))
    # measured: F@1% 1.000 (the outlines lie 1.5 px either side), Chamfer 1.39 px, two curves
    assert po["f@1%"] > 0.99 and 1.0 < po["chamfer_px"] < 1.8 and po["curves_pred"] == 2 and po["iou"] > 0.8


def test_skeleton_finds_the_t_junction_and_its_ends():
    d = drawing("t_curved")
    r = _score(d, skeleton_trace(d.ink))
    assert (r["junction_tp"], r["junction_pred"]) == (1, 1) and r["endpoint_tp"] == 3 and r["curves_pred"] == 3


@pytest.mark.slow
def test_quick_run_writes_its_table(tmp_path):
    from benchmarks.table_curves import main

    main([str(tmp_path), "--quick"])
    text = (tmp_path / "table.md").read_text()
    assert "Commit:" in text and "Machine:" in text and "thread" in text
    for method in ("ipm", "ipm_points", "skeleton", "potrace"):
        assert f"| {method} |" in text
    rows = (tmp_path / "rows.csv").read_text().splitlines()
    assert len(rows) == 1 + 4 * 4
    assert (tmp_path / "contact.png").stat().st_size > 10_000
    # the degraded set: its own table, rows and sheets, and its means at the end of table.md
    assert "## The degraded set: means over the drawings" in text
    deg = (tmp_path / "table_degraded.md").read_text()
    assert "Commit:" in deg and "*clean* strokes" in deg and all(f"| {m} |" in deg for m in ("ipm", "skeleton"))
    assert len((tmp_path / "rows_degraded.csv").read_text().splitlines()) == 1 + 4 * 4
    for png in ("contact_degraded.png", "inputs_degraded.png"):
        assert (tmp_path / png).stat().st_size > 10_000
