"""Tables from bench rows: mean ± std over seeds, best per column in bold; Markdown, CSV and LaTeX; and
means per class of target (a class's mean is over its targets of each target's mean over seeds)."""

from __future__ import annotations

import csv
import io
from collections import defaultdict

import numpy as np

# (row key, column title, higher is better; None: no best)
METRICS = [("heldout_iou", "held-out IoU", True), ("fscore@0.02", "F@0.02", True), ("fscore@0.05", "F@0.05", True),
           ("chamfer_l1", "Chamfer-L1", False), ("iou_3d", "3D IoU", True), ("param_error", "param. error", False),
           ("discrete_accuracy", "discrete acc.", True), ("align_scale", "scale about the eye (K = 1)", None),
           ("wall_time_s", "time (s)", False), ("evaluations", "evals", False)]
# the metrics given per class
CLASS_METRICS = ("heldout_iou", "fscore@0.02", "fscore@0.05", "chamfer_l1", "iou_3d")


def aggregate(rows: list[dict]) -> dict:
    """{(method, views, target): {metric: (mean, std, n)}} over the seeds of successful rows."""
    groups: dict = defaultdict(lambda: defaultdict(list))
    for r in rows:
        if r.get("status") != "ok":
            continue
        for key, _, _ in METRICS:
            if key in r:
                groups[(r["method"], r["views"], r["target"])][key].append(float(r[key]))
    return {g: {k: (float(np.mean(v)), float(np.std(v)), len(v)) for k, v in m.items()} for g, m in groups.items()}


def table(rows: list[dict], metric: str = "heldout_iou") -> tuple[list[str], list[list[str]], list[list[float]]]:
    """Rows = method × views, columns = targets, cells = 'mean ± std' of one metric over the seeds (just
    the value when there is one seed)."""
    agg = aggregate(rows)
    targets = sorted({g[2] for g in agg})
    lines = sorted({(g[0], g[1]) for g in agg})
    header = ["method", "views"] + targets
    body, values = [], []
    for m, k in lines:
        cells, vals = [m, str(k)], []
        for t in targets:
            v = agg.get((m, k, t), {}).get(metric)
            cells.append("-" if v is None else f"{v[0]:.3f} ± {v[1]:.3f}" if v[2] > 1 else f"{v[0]:.3f}")
            vals.append(np.nan if v is None else v[0])
        body.append(cells)
        values.append(vals)
    return header, body, values


def _bold_best(body, values, higher: bool | None, fmt):
    if higher is None:
        return body
    arr = np.array(values, dtype=float) if values else np.zeros((0, 0))
    for j in range(arr.shape[1] if arr.size else 0):
        col = arr[:, j]
        if np.all(np.isnan(col)):
            continue
        best = np.nanmax(col) if higher else np.nanmin(col)
        for i in range(len(body)):
            if not np.isnan(col[i]) and col[i] == best:
                body[i][j + 2] = fmt(body[i][j + 2])
    return body


def class_table(rows: list[dict], classes: dict[str, str], metric: str = "heldout_iou"
                ) -> tuple[list[str], list[list[str]], list[list[float]]]:
    """Rows = method × views, columns = classes (``classes``: target -> class), cells = the mean over the
    class's targets of each target's mean over seeds; a cell over only some of the class's targets says
    how many (``0.912 (2/3)``) and has the value NaN (it is not compared with whole classes)."""
    agg = aggregate(rows)
    members: dict[str, list[str]] = defaultdict(list)
    for t, c in classes.items():
        members[c].append(t)
    names = sorted(members)
    lines = sorted({(g[0], g[1]) for g in agg})
    body, values = [], []
    for m, k in lines:
        cells, vals = [m, str(k)], []
        for c in names:
            got = [agg[(m, k, t)][metric][0] for t in members[c] if metric in agg.get((m, k, t), {})]
            if not got:
                cells.append("-")
                vals.append(np.nan)
                continue
            v = float(np.mean(got))
            whole = len(got) == len(members[c])
            cells.append(f"{v:.3f}" + ("" if whole else f" ({len(got)}/{len(members[c])})"))
            vals.append(v if whole else np.nan)  # a mean over part of a class does not compete
        body.append(cells)
        values.append(vals)
    return ["method", "views"] + names, body, values


def _section(title: str, higher: bool | None, header, body, values) -> list[str]:
    """A Markdown table with the best value (not NaN) per column in bold, rows without any cell dropped."""
    keep = [i for i, b in enumerate(body) if any(c != "-" for c in b[2:])]
    if not keep:
        return []
    body, values = [body[i] for i in keep], [values[i] for i in keep]
    body = _bold_best([list(b) for b in body], values, higher, lambda s: f"**{s}**")
    sense = "" if higher is None else f" ({'higher' if higher else 'lower'} is better)"
    return ([f"### {title}{sense}", "", "| " + " | ".join(header) + " |", "|" + "---|" * len(header)]
            + ["| " + " | ".join(b) + " |" for b in body] + [""])


def class_markdown(rows: list[dict], classes: dict[str, str]) -> str:
    """The per-class tables of :data:`CLASS_METRICS` (empty when no target has a class)."""
    if not classes:
        return ""
    out = []
    for key, title, higher in METRICS:
        if key in CLASS_METRICS:
            out += _section(f"{title} per class, mean over its targets", higher, *class_table(rows, classes, key))
    return "\n".join(out)


def class_summary(rows: list[dict], classes: dict[str, str], fits: set[str], *, reference_views: int = 12,
                  metric: str = "heldout_iou") -> str:
    """Per class and K: the generator fit (methods in ``fits``) against the best other method at the same
    K and at ``reference_views``, with the gaps, as a Markdown table (empty without classes or fits).

    Only methods with a value on every target of the class compete (no mean over a subset)."""
    if not classes or not fits:
        return ""
    header, body, values = class_table(rows, classes, metric)
    names, full = header[2:], values
    lines = ["| class | K | generator fit | best other, same K | gap | best other, "
             f"{reference_views} views | gap |", "|---|---|---|---|---|---|---|"]

    def best(j: int, k: int) -> tuple[float, str]:
        cand = [(full[i][j], b[0]) for i, b in enumerate(body)
                if b[0] not in fits and int(b[1]) == k and not np.isnan(full[i][j])]
        return max(cand) if cand else (np.nan, "-")

    def cell(v: float, who: str) -> str:
        return "-" if np.isnan(v) else f"{v:.3f} ({who})"

    def gap(a: float, b: float) -> str:
        return "-" if np.isnan(a) or np.isnan(b) else f"{a - b:+.3f}"

    for j, c in enumerate(names):
        for i, b in enumerate(body):
            if b[0] not in fits or np.isnan(full[i][j]):
                continue
            k, v = int(b[1]), full[i][j]
            same, ref = best(j, k), best(j, reference_views)
            lines.append(f"| {c} | {k} | {v:.3f} ({b[0]}) | {cell(*same)} | {gap(v, same[0])} | "
                         f"{cell(*ref)} | {gap(v, ref[0])} |")
    return "\n".join(lines) + "\n" if len(lines) > 2 else ""


def hidden_markdown(rows: list[dict]) -> str:
    """Which discrete parts of generator samples the input views hide (DESIGN.md: tables say so), one line
    per target, number of views and cues given besides the masks (rows of methods given depth or part
    labels see more); empty when no row knows (real meshes)."""
    seen: dict[tuple[str, int, tuple[str, ...]], dict] = {}
    for r in rows:
        if r.get("status") == "ok" and "hidden_discrete" in r:
            seen.setdefault((r["target"], r["views"], tuple(r.get("cues", ()))), r["hidden_discrete"])
    if not seen:
        return ""
    from ipm.bench.protocol import HIDDEN_TOLERANCE
    from ipm.losses.cues import DEPTH_KNEE

    lines = ["### Discrete parts the input views hide", "",
             "A discrete parameter is listed when a neighbouring value draws the same input masks (within "
             f"{100 * HIDDEN_TOLERANCE:g} % of the target's pixels in each view): no method can tell it from the "
             f"views. With cues, also the same depth (within {100 * DEPTH_KNEE:g} % of the view's median depth) "
             "and the same part labels.", ""]
    for (t, k, cues), hidden in sorted(seen.items()):
        what = ", ".join(f"{n} (also {', '.join(map(str, v))})" for n, v in sorted(hidden.items())) or "none"
        given = f" with {', '.join(cues)}" if cues else ""
        lines.append(f"- {t}, {k} view{'s' if k > 1 else ''}{given}: {what}")
    return "\n".join(lines) + "\n"


def markdown(rows: list[dict]) -> str:
    """The report: one Markdown table per metric (the best per target in bold), the notes on hidden
    parameters and the failed cells."""
    out = []
    for key, title, higher in METRICS:
        out += _section(title, higher, *table(rows, key))
    hidden = hidden_markdown(rows)
    if hidden:
        out.append(hidden)
    failed = [r for r in rows if r.get("status") != "ok"]
    if failed:
        out += ["### Failed cells", ""] + [f"- {r['key']}: {r.get('error', '')}" for r in failed] + [""]
    return "\n".join(out)


def latex(rows: list[dict], metric: str = "heldout_iou") -> str:
    """One metric's table as a LaTeX ``tabular`` (booktabs rules; the best per target in bold)."""
    higher = next(h for k, _, h in METRICS if k == metric)
    header, body, values = table(rows, metric)
    body = _bold_best([list(b) for b in body], values, higher, lambda s: "\\textbf{" + s + "}")
    lines = ["\\begin{tabular}{" + "l" * len(header) + "}", "\\toprule", " & ".join(header) + " \\\\", "\\midrule"]
    lines += [" & ".join(c.replace("±", "$\\pm$") for c in b) + " \\\\" for b in body]
    lines += ["\\bottomrule", "\\end{tabular}"]
    return "\n".join(lines) + "\n"


def csv_text(rows: list[dict]) -> str:
    """One CSV line per (method, views, target): mean and std of every metric over the seeds, and ``n``."""
    agg = aggregate(rows)
    buf = io.StringIO()
    w = csv.writer(buf)
    w.writerow(["method", "views", "target"] + [f"{k}_{s}" for k, _, _ in METRICS for s in ("mean", "std")] + ["n"])
    for (m, k, t), vals in sorted(agg.items()):
        n = max((v[2] for v in vals.values()), default=0)
        w.writerow([m, k, t] + [x for key, _, _ in METRICS for x in (vals[key][:2] if key in vals else ("", ""))] + [n])
    return buf.getvalue()
