"""The vectorization table (``make table-curves``): raster line drawings with exact curves, vectorized by
ipm (``ipm.curves.vectorize``: the zero set of a fitted piecewise bicubic implicit function) and by two
baselines (``benchmarks.curve_baselines``: skeleton + graph tracing; potrace's outlines), each scored
against the exact curve network (``benchmarks.curve_metrics``).

Drawings: ``benchmarks.drawings`` (22, 256 x 256, 3 px anti-aliased strokes: circles, ellipses, crossings,
T-junctions, open arcs and S-curves, random Bezier networks with junctions, outlines of 2D ``ipm.sdf``
trees). ``--quick``: four of them. ``--real DIR``: also every PNG/JPEG in DIR (dark strokes on a light
ground), reported only by what needs no ground truth: re-render IoU, curve counts, seconds.

Two sets (``--sets``, both by default): ``clean``, the drawings as rendered, and ``degraded``, their copies
as scans and sketches look (``benchmarks.drawings.degrade``: stroke half-width varying 1..2.5 px along the
curves, Gaussian blur of 0.7 px, a faint paper tone, Gaussian noise of sigma 0.1, clipped to [0, 1]; seed
0), scored against the same truth; their re-render IoU compares with the *clean* strokes.

Writes ``table.md`` (header: command, commit, machine, torch threads; one block per method: every
drawing and the mean; at its end the degraded set's means), ``rows.csv`` and ``contact.png`` (a few
drawings with every method's curves) for the clean set, and ``table_degraded.md``, ``rows_degraded.csv``,
``contact_degraded.png`` and ``inputs_degraded.png`` (a few inputs, clean above degraded) for the other.

``ipm_points`` is a diagnostic row: the same fit as ``ipm`` scored on its polylines before the Bezier fit.

Usage: ``python -m benchmarks.table_curves [OUT_DIR] [--quick] [--real DIR] [--methods ipm,skeleton,...]
[--sets clean,degraded]``
"""

from __future__ import annotations

import argparse
import csv
import datetime as _dt
import io
import logging
import math
import os
import platform
import subprocess
import sys
import time
from collections.abc import Callable
from pathlib import Path

import numpy as np
import torch

from benchmarks.curve_baselines import potrace_outline, skeleton_trace
from benchmarks.curve_metrics import THRESHOLDS, Traced, iou, score, stroke_mask
from benchmarks.drawings import (
    BLUR,
    DEGRADE_HALF_WIDTH,
    NOISE,
    PAPER,
    Drawing,
    make_degraded,
    make_drawings,
    quick_degraded,
    quick_drawings,
)

ROOT = Path(__file__).resolve().parents[1]
THREADS = 1
CONTACT = ("circle_r80", "x_curved", "t_curved", "net_3", "sdf_frame_hole", "sdf_rect_circle")
F_KEYS = tuple(f"f@{100 * t:g}%" for t in THRESHOLDS)
SETS = ("clean", "degraded")


def _bezier_points(beziers: np.ndarray, step: float = 0.1) -> np.ndarray:
    """A chain of cubic Beziers ``(m, 4, 2)`` sampled about every ``step`` px -> ``(n, 2)``."""
    out = [beziers[0, :1]]
    for c in beziers:
        n = max(2, math.ceil(np.linalg.norm(np.diff(c, axis=0), axis=1).sum() / step))
        t = np.linspace(0.0, 1.0, n + 1)[1:, None]
        out.append((1 - t) ** 3 * c[0] + 3 * (1 - t) ** 2 * t * c[1] + 3 * (1 - t) * t ** 2 * c[2] + t ** 3 * c[3])
    return np.concatenate(out)


_LAST: dict = {}


def _vectorized(ink: np.ndarray):
    """ipm's result on ``ink`` and its seconds, kept for the drawing at hand (both ipm rows share one fit)."""
    from ipm.curves import VectorizeSettings, vectorize

    key = hash(np.ascontiguousarray(ink).tobytes())
    if key not in _LAST:
        _LAST.clear()
        t0 = time.perf_counter()
        v = vectorize(ink, VectorizeSettings(cell=8, width=None, seed=0))
        _LAST[key] = (v, time.perf_counter() - t0)
    return _LAST[key]


def _ipm_traced(ink: np.ndarray, beziers: bool) -> Traced:
    from ipm.curves import render_strokes

    v, seconds = _vectorized(ink)
    curves, closed = [], []
    for c in v.curves:
        bez = np.asarray(c.beziers, dtype=np.float64).reshape(-1, 4, 2)
        p = _bezier_points(bez) if beziers and len(bez) else np.asarray(c.points, dtype=np.float64).reshape(-1, 2)
        if c.closed and len(p) > 1 and np.allclose(p[0], p[-1]):
            p = p[:-1]
        curves.append(p)
        closed.append(bool(c.closed))
    strokes = (np.asarray(render_strokes(v, v.size, v.width), dtype=bool) if beziers
               else stroke_mask(curves, closed, v.size, v.width))
    return Traced(tuple(curves), tuple(closed), np.asarray(v.junctions, dtype=np.float64).reshape(-1, 2),
                  np.asarray(v.endpoints, dtype=np.float64).reshape(-1, 2), strokes, seconds)


def vectorize_ipm(ink: np.ndarray) -> Traced:
    """ipm: ``vectorize(ink, VectorizeSettings(cell=8, width=None, seed=0))``, scored on what its SVG holds:
    each curve's Bezier chain, re-rendered as strokes of its own half-width (``render_strokes``)."""
    return _ipm_traced(ink, beziers=True)


def vectorize_ipm_points(ink: np.ndarray) -> Traced:
    """The same fit scored on its polylines (``Curve.points``, before the Bezier fit), re-rendered as
    strokes of the same half-width: how much the Bezier fit's tolerance costs."""
    return _ipm_traced(ink, beziers=False)


METHODS: dict[str, Callable[[np.ndarray], Traced]] = {
    "ipm": vectorize_ipm, "ipm_points": vectorize_ipm_points, "skeleton": skeleton_trace, "potrace": potrace_outline}
LABELS = {"ipm": "ipm (implicit bicubic zero set; its SVG's Beziers)",
          "ipm_points": "ipm's polylines before the Bezier fit (diagnostic: the same fit as ipm)",
          "skeleton": "skeleton + graph tracing", "potrace": "potrace (outlines, potracer defaults)"}


# -- the header: what ran where ------------------------------------------------------------------------

def _git(*args: str) -> str:
    try:
        return subprocess.run(["git", *args], cwd=ROOT, capture_output=True, text=True, timeout=30).stdout.strip()
    except (OSError, subprocess.SubprocessError):
        return ""


def header(command: str, wall: float) -> list[str]:
    commit = _git("rev-parse", "--short", "HEAD") or "unknown"
    mine = ["benchmarks/table_curves.py", "benchmarks/drawings.py", "benchmarks/curve_metrics.py",
            "benchmarks/curve_baselines.py", "ipm/curves"]
    dirty = _git("status", "--porcelain", "--", *mine)
    cpu = platform.machine()
    try:
        cpu = next(line.split(":", 1)[1].strip() for line in Path("/proc/cpuinfo").read_text().splitlines()
                   if line.startswith("model name"))
    except (OSError, StopIteration):
        pass
    return [f"Command: `{command}`  ",
            f"Commit: {commit}" + (" (plus uncommitted changes to the benchmark or ipm/curves)" if dirty else "")
            + "  ",
            f"Machine: {platform.node()} ({cpu}, {os.cpu_count()} cores), torch {torch.__version__} with "
            f"{torch.get_num_threads()} thread(s), Python {platform.python_version()}  ",
            f"Date: {_dt.datetime.now(_dt.UTC).isoformat(timespec='seconds')}, wall time {wall:.0f} s"]


# -- running -----------------------------------------------------------------------------------------------

def _run_one(fn: Callable[[np.ndarray], Traced], ink: np.ndarray) -> tuple[Traced, float, str]:
    t0 = time.perf_counter()
    try:
        traced, error = fn(ink), ""
    except Exception as exc:  # a method that fails on a drawing scores as empty, and the table says why
        logging.getLogger(__name__).exception("method failed")
        traced, error = Traced((), ()), f"{type(exc).__name__}: {exc}"
    seconds = time.perf_counter() - t0
    return traced, (traced.seconds if traced.seconds is not None else seconds), error


def score_drawings(drawings: tuple[Drawing, ...], methods: tuple[str, ...]) -> tuple[list[dict], dict]:
    """Every method on every drawing -> rows and the traced results ``{(drawing, method): Traced}``."""
    rows, traced = [], {}
    for d in drawings:
        for m in methods:
            t, seconds, error = _run_one(METHODS[m], d.ink)
            traced[(d.name, m)] = t
            r = score(t, d.curves, d.closed, d.junctions, d.endpoints, d.truth_ink)    # IoU: the clean strokes
            rows.append({"drawing": d.name, "family": d.family, "method": m, **r, "seconds": seconds, "error": error})
            print(f"{d.name:20s} {m:9s} F@1% {r['f@1%']:.3f}  Chamfer {r['chamfer_px']:.2f} px  "
                  f"IoU {r['iou']:.3f}  {seconds:.1f} s{'  ' + error if error else ''}", flush=True)
    return rows, traced


def read_real(folder: Path, size: int = 256) -> list[tuple[str, np.ndarray]]:
    """Every PNG / JPEG in ``folder`` as ink ``(H, W) float`` in [0, 1] (dark strokes on a light ground;
    the longer side scaled to ``size``)."""
    import cv2

    out = []
    for path in sorted(p for p in folder.iterdir() if p.suffix.lower() in (".png", ".jpg", ".jpeg")):
        img = cv2.imread(str(path), cv2.IMREAD_UNCHANGED)
        if img is None:
            continue
        if img.ndim == 3 and img.shape[2] == 4:          # transparent ground: composite on white
            a = img[..., 3:4].astype(np.float64) / 255.0
            img = (img[..., :3] * a + 255.0 * (1 - a)).astype(np.uint8)
        grey = img if img.ndim == 2 else cv2.cvtColor(img, cv2.COLOR_BGR2GRAY)
        s = size / max(grey.shape)
        grey = cv2.resize(grey, (round(grey.shape[1] * s), round(grey.shape[0] * s)), interpolation=cv2.INTER_AREA)
        out.append((path.stem, 1.0 - grey.astype(np.float64) / 255.0))
    return out


def score_real(images: list[tuple[str, np.ndarray]], methods: tuple[str, ...]) -> list[dict]:
    rows = []
    for name, ink in images:
        for m in methods:
            t, seconds, error = _run_one(METHODS[m], ink)
            rows.append({"drawing": name, "method": m, "curves_pred": len(t.curves),
                         "iou": iou(t.strokes, ink > 0.5) if t.strokes is not None else float("nan"),
                         "seconds": seconds, "error": error})
            print(f"{name:20s} {m:9s} IoU {rows[-1]['iou']:.3f}  {seconds:.1f} s", flush=True)
    return rows


# -- the table ---------------------------------------------------------------------------------------------

def _f(x: float, digits: int = 3) -> str:
    return "—" if x is None or (isinstance(x, float) and math.isnan(x)) else f"{x:.{digits}f}"


def _pooled(rows: list[dict], kind: str) -> tuple[float, float]:
    tp = sum(r[f"{kind}_tp"] for r in rows)
    pred, true = sum(r[f"{kind}_pred"] for r in rows), sum(r[f"{kind}_true"] for r in rows)
    return (tp / pred if pred else float("nan")), (tp / true if true else float("nan"))


def mean_row(rows: list[dict]) -> dict:
    """The mean over drawings (F, Chamfer, IoU, seconds); junction and endpoint precision / recall pooled
    over all drawings' points; curve counts summed, with the share of drawings whose count is exact."""
    out = {k: float(np.mean([r[k] for r in rows])) for k in (*F_KEYS, "chamfer_px", "chamfer_diag", "seconds")}
    ious = [r["iou"] for r in rows if not math.isnan(r["iou"])]
    out["iou"] = float(np.mean(ious)) if ious else float("nan")
    for kind in ("junction", "endpoint"):
        out[f"{kind}_p"], out[f"{kind}_r"] = _pooled(rows, kind)
    out["curves_pred"] = sum(r["curves_pred"] for r in rows)
    out["curves_true"] = sum(r["curves_true"] for r in rows)
    out["count_exact"] = float(np.mean([r["curves_pred"] == r["curves_true"] for r in rows]))
    out["failed"] = sum(bool(r["error"]) for r in rows)
    return out


def _line(name: str, r: dict) -> str:
    cells = [name, *(_f(r[k]) for k in F_KEYS), _f(r["chamfer_px"], 2),
             f"{_f(r['junction_p'], 2)} / {_f(r['junction_r'], 2)}",
             f"{_f(r['endpoint_p'], 2)} / {_f(r['endpoint_r'], 2)}",
             f"{r['curves_pred']} / {r['curves_true']}",
             _f(r["iou"]), _f(r["seconds"], 2)]
    return "| " + " | ".join(cells) + " |"


def summary_table(rows: list[dict], methods: tuple[str, ...]) -> list[str]:
    """One line per method: its mean row, the share of exact curve counts and its failures."""
    cols = [*(f"F@{k[2:]}" for k in F_KEYS), "Chamfer px", "junction P / R", "endpoint P / R",
            "curves pred / true", "re-render IoU", "s"]
    out = ["| method | " + " | ".join(cols) + " | exact curve count | failed |", "|" + "---|" * (len(cols) + 3)]
    for m in methods:
        mine = [r for r in rows if r["method"] == m]
        if mine:
            mean = mean_row(mine)
            out.append(_line(m, mean)[:-1] + f"| {100 * mean['count_exact']:.0f} % | {mean['failed']} |")
    return out


def table(rows: list[dict], methods: tuple[str, ...]) -> str:
    cols = ["drawing", *(f"F@{k[2:]}" for k in F_KEYS), "Chamfer px", "junction P / R", "endpoint P / R",
            "curves pred / true", "re-render IoU", "s"]
    out = []
    for m in methods:
        mine = [r for r in rows if r["method"] == m]
        if not mine:
            continue
        mean = mean_row(mine)
        out += [f"### {LABELS.get(m, m)}", "", "| " + " | ".join(cols) + " |", "|" + "---|" * len(cols)]
        out += [_line(r["drawing"] + (" (failed)" if r["error"] else ""), r) for r in mine]
        out += [_line("**mean**", mean), ""]
        errors = [f"- {r['drawing']}: {r['error']}" for r in mine if r["error"]]
        out += ([*errors, ""] if errors else [])
    return "\n".join(["## Means over the drawings", "", *summary_table(rows, methods), "", *out])


def real_table(rows: list[dict], methods: tuple[str, ...]) -> str:
    out = ["## Real drawings (no ground truth)", "", "| drawing | " + " | ".join(
        f"{m}: curves / IoU / s" for m in methods) + " |", "|" + "---|" * (len(methods) + 1)]
    for name in dict.fromkeys(r["drawing"] for r in rows):
        cells = []
        for m in methods:
            r = next(r for r in rows if r["drawing"] == name and r["method"] == m)
            cells.append(f"{r['curves_pred']} / {_f(r['iou'])} / {_f(r['seconds'], 1)}")
        out.append(f"| {name} | " + " | ".join(cells) + " |")
    return "\n".join(out) + "\n"


NOTES = """- Drawings: 256 x 256, strokes of half-width 1.5 px rendered with exact distance coverage
  (`benchmarks/drawings.py`); the truth is the curve network split at junctions (an X is 4 curves).
- F at 0.25 / 0.5 / 1 / 2 % of the diagonal (362 px) = 0.91 / 1.81 / 3.62 / 7.24 px; 0.25 % is ours, the
  issue's are the other three. Chamfer: mean of the two one-sided mean distances (exact point-to-polyline),
  every curve resampled every <= 0.25 px.
- Junctions and endpoints match one-to-one within 2 % of the diagonal (7.2 px); in a mean row P / R are
  pooled over all drawings' points; "—" where undefined (0 / 0).
- Re-render IoU against `ink > 0.5`, each method's own rendering: ipm, its SVG's Beziers as strokes of its
  estimated half-width (`render_strokes`); ipm_points, its polylines as strokes of that half-width;
  skeleton, its curves as strokes of half-width area / (2 length); potrace, the even-odd fill of its outlines.
- A method that raises on a drawing scores as empty (F 0, Chamfer one diagonal) and is marked failed.
- The rectangles' edges in sdf_rect_circle and sdf_frame_hole lie on pixel boundaries: there a stroke is two
  rows of full ink between two rows of ink exactly 0.5 (not stroke), a centre line with no pixel row on it.
- potrace traces outlines, so each stroke yields two curves about 1.5 px either side of the true one:
  scored as is (what potrace gives a user), it finds no junctions or endpoints by construction."""

DEGRADED_NOTES = f"""- The degraded set: each of the clean set's drawings redrawn as scans and sketches look
  (`benchmarks.drawings.degrade`, seed 0), with the same ground truth: strokes of a half-width varying
  smoothly along the curves between {DEGRADE_HALF_WIDTH[0]:g} and {DEGRADE_HALF_WIDTH[1]:g} px (a random
  smooth field of position, wavelengths 48..128 px, spanning the whole range on every drawing), blurred by a
  Gaussian of sigma {BLUR:g} px, laid on paper with a smooth tone of at most {PAPER:g}, plus i.i.d. Gaussian
  noise of sigma {NOISE:g} per pixel, clipped to [0, 1]. `inputs_degraded.png` shows a few, clean above.
- Every method gets the degraded ink as is (the baselines binarize it at 0.5, as on the clean set; no
  method is told the noise level or the width).
- Re-render IoU compares with the *clean* strokes, the truth's `ink > 0.5` (half-width 1.5 px), not with
  the degraded input, whose strokes are 2 to 5 px wide: a method that re-renders the input's own strokes
  exactly cannot reach 1 ({{input_iou}}).
- Otherwise as the clean set's table (`table.md`): F at 0.25 / 0.5 / 1 / 2 % of the diagonal, Chamfer,
  junctions and endpoints within 2 % of the diagonal, a method that raises scores as empty."""


def input_iou(drawings: tuple[Drawing, ...]) -> str:
    """What the degraded inputs themselves score against the clean strokes (the IoU's ceiling, roughly)."""
    from benchmarks.curve_metrics import iou as _iou

    got = [_iou(d.ink > 0.5, d.truth_ink > 0.5) for d in drawings]
    return f"the degraded input's own `ink > 0.5` has mean IoU {np.mean(got):.3f} with the clean strokes"


def contact_sheet(path: Path, drawings: tuple[Drawing, ...], traced: dict, methods: tuple[str, ...]) -> None:
    """A grid: one row per drawing; the ink with the true curves, then each method's curves over the ink
    (junctions red, endpoints green)."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    picks = [d for d in drawings if d.name in CONTACT] or list(drawings[:4])
    cols = 1 + len(methods)
    fig, axes = plt.subplots(len(picks), cols, figsize=(2.6 * cols, 2.6 * len(picks)), squeeze=False)
    for row, d in zip(axes, picks):
        panels = [("truth", Traced(d.curves, d.closed, d.junctions, d.endpoints))]
        panels += [(m, traced[(d.name, m)]) for m in methods]
        for ax, (title, t) in zip(row, panels):
            ax.imshow(d.ink, cmap="Greys", vmin=0, vmax=2.5, extent=(0, d.ink.shape[1], d.ink.shape[0], 0))
            for c, cl in zip(t.curves, t.closed):
                p = np.concatenate([c, c[:1]]) if cl and len(c) else c
                ax.plot(p[:, 0], p[:, 1], lw=0.8)
            if len(t.junctions):
                ax.plot(t.junctions[:, 0], t.junctions[:, 1], "o", ms=4, mfc="none", mec="red")
            if len(t.endpoints):
                ax.plot(t.endpoints[:, 0], t.endpoints[:, 1], "s", ms=3, mfc="none", mec="green")
            ax.set_title(f"{d.name}: {title}" if title == "truth" else f"{title} ({len(t.curves)} curves)", fontsize=7)
            ax.set_xticks([])
            ax.set_yticks([])
    _save_png(fig, path)


def _save_png(fig, path: Path) -> None:
    """Write a matplotlib figure to ``path`` as PNG, atomically, and close it."""
    import matplotlib.pyplot as plt

    from ipm.files import write_bytes

    fig.tight_layout()
    buf = io.BytesIO()
    fig.savefig(buf, format="png", dpi=110)
    plt.close(fig)
    write_bytes(path, buf.getvalue())


def inputs_sheet(path: Path, drawings: tuple[Drawing, ...]) -> None:
    """A few degraded inputs (bottom row) under their clean drawings (top row), as a reader sees them."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    picks = [d for d in drawings if d.name in CONTACT] or list(drawings[:4])
    fig, axes = plt.subplots(2, len(picks), figsize=(2.8 * len(picks), 5.8), squeeze=False)
    for k, d in enumerate(picks):
        for row, (img, what) in enumerate(((d.truth_ink, "clean"), (d.ink, "degraded"))):
            ax = axes[row, k]
            ax.imshow(1.0 - img, cmap="gray", vmin=0, vmax=1, interpolation="nearest")
            ax.set_title(f"{d.name}: {what}", fontsize=8)
            ax.set_xticks([])
            ax.set_yticks([])
    _save_png(fig, path)


def write_csv(path: Path, rows: list[dict]) -> None:
    from ipm.files import write_text

    cols = list(dict.fromkeys(k for r in rows for k in r))
    buf = io.StringIO()
    w = csv.DictWriter(buf, fieldnames=cols, lineterminator="\n")
    w.writeheader()
    for r in rows:
        w.writerow({k: (f"{v:.6g}" if isinstance(v, float) else v) for k, v in r.items()})
    write_text(path, buf.getvalue())


def run(out_dir: Path, quick: bool = False, real: Path | None = None,
        methods: tuple[str, ...] = tuple(METHODS), command: str | None = None,
        sets: tuple[str, ...] = SETS) -> list[dict]:
    """Score ``methods`` on the drawing ``sets`` (the clean one first, as before the degraded set existed)
    and write the tables -> the rows (the degraded set's after the clean set's, with ``"set": "degraded"``)."""
    from ipm.files import write_text

    torch.set_num_threads(THREADS)
    command = command or "python -m benchmarks.table_curves " + " ".join(sys.argv[1:])
    out_dir.mkdir(parents=True, exist_ok=True)
    rows: list[dict] = []
    deg_rows: list[dict] = []
    if "clean" in sets:
        t0 = time.perf_counter()
        drawings = quick_drawings() if quick else make_drawings()
        rows, traced = score_drawings(drawings, methods)
        real_rows = score_real(read_real(real), methods) if real else []
        write_csv(out_dir / "rows.csv", rows)
        if real_rows:
            write_csv(out_dir / "real_rows.csv", real_rows)
        contact_sheet(out_dir / "contact.png", drawings, traced, methods)
        clean_text = ["# Vectorizing raster line drawings (issue: `make table-curves`)", "",
                      *header(command, time.perf_counter() - t0), "", NOTES, "", table(rows, methods)]
        if real_rows:
            clean_text += ["", real_table(real_rows, methods)]
    if "degraded" in sets:
        t0 = time.perf_counter()
        drawings = quick_degraded() if quick else make_degraded()
        print("-- the degraded set", flush=True)
        deg_rows, traced = score_drawings(drawings, methods)
        deg_rows = [{"set": "degraded", **r} for r in deg_rows]
        write_csv(out_dir / "rows_degraded.csv", deg_rows)
        contact_sheet(out_dir / "contact_degraded.png", drawings, traced, methods)
        inputs_sheet(out_dir / "inputs_degraded.png", drawings)
        notes = DEGRADED_NOTES.replace("{input_iou}", input_iou(drawings))
        text = ["# Vectorizing degraded raster line drawings (issue: `make table-curves`)", "",
                *header(command, time.perf_counter() - t0), "", notes, "", table(deg_rows, methods)]
        write_text(out_dir / "table_degraded.md", "\n".join(text) + "\n")
    if "clean" in sets:
        if deg_rows:
            clean_text += ["", "## The degraded set: means over the drawings", "",
                           "The same drawings and truth as scans and sketches look (blur, noise, varying stroke "
                           "width; re-render IoU against the clean strokes): every drawing and the notes in "
                           "`table_degraded.md`.", "", *summary_table(deg_rows, methods)]
        write_text(out_dir / "table.md", "\n".join(clean_text) + "\n")
    return rows + deg_rows


def main(argv: list[str] | None = None) -> None:
    ap = argparse.ArgumentParser(prog="python -m benchmarks.table_curves", description=__doc__.split("\n\n")[0])
    ap.add_argument("out_dir", nargs="?", default="results/table_curves", type=Path)
    ap.add_argument("--quick", action="store_true", help="four drawings (a test run)")
    ap.add_argument("--real", type=Path, default=None, help="a folder of real line drawings (PNG / JPEG)")
    ap.add_argument("--methods", default=",".join(METHODS), help=f"comma-separated, of {', '.join(METHODS)}")
    ap.add_argument("--sets", default=",".join(SETS),
                    help="comma-separated, of clean (the drawings as rendered: table.md) and degraded (as scans "
                    "and sketches look: table_degraded.md); both by default")
    args = ap.parse_args(argv)
    methods = tuple(m.strip() for m in args.methods.split(",") if m.strip())
    unknown = [m for m in methods if m not in METHODS]
    if unknown:
        ap.error(f"unknown method(s) {', '.join(unknown)}; expected some of {', '.join(METHODS)}")
    sets = tuple(s.strip() for s in args.sets.split(",") if s.strip())
    if not sets or any(s not in SETS for s in sets):
        ap.error(f"--sets: expected some of {', '.join(SETS)}, got {args.sets!r}")
    if args.real is not None and not args.real.is_dir():
        ap.error(f"--real: expected a folder, got {args.real}")
    run(args.out_dir, args.quick, args.real, methods, sets=sets)


if __name__ == "__main__":
    main()
