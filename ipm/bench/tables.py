"""Tables from bench rows: mean ± std over seeds, best per column in bold; Markdown, CSV and LaTeX."""

from __future__ import annotations

import csv
import io
from collections import defaultdict

import numpy as np

# (row key, column title, higher is better)
METRICS = [("heldout_iou", "held-out IoU", True), ("fscore@0.02", "F@0.02", True), ("fscore@0.05", "F@0.05", True),
           ("chamfer_l1", "Chamfer-L1", False), ("iou_3d", "3D IoU", True), ("param_error", "param. error", False),
           ("discrete_accuracy", "discrete acc.", True), ("wall_time_s", "time (s)", False),
           ("evaluations", "evals", False)]


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


def _bold_best(body, values, higher: bool, fmt):
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


def markdown(rows: list[dict]) -> str:
    out = []
    for key, title, higher in METRICS:
        header, body, values = table(rows, key)
        if not body or all(all(np.isnan(v) for v in r) for r in values):
            continue
        keep = [i for i, r in enumerate(values) if not all(np.isnan(v) for v in r)]  # rows with a value
        body, values = [body[i] for i in keep], [values[i] for i in keep]
        body = _bold_best([list(b) for b in body], values, higher, lambda s: f"**{s}**")
        out += [f"### {title} ({'higher' if higher else 'lower'} is better)", "",
                "| " + " | ".join(header) + " |", "|" + "---|" * len(header)]
        out += ["| " + " | ".join(b) + " |" for b in body]
        out.append("")
    failed = [r for r in rows if r.get("status") != "ok"]
    if failed:
        out += ["### Failed cells", ""] + [f"- {r['key']}: {r.get('error', '')}" for r in failed] + [""]
    return "\n".join(out)


def latex(rows: list[dict], metric: str = "heldout_iou") -> str:
    higher = next(h for k, _, h in METRICS if k == metric)
    header, body, values = table(rows, metric)
    body = _bold_best([list(b) for b in body], values, higher, lambda s: "\\textbf{" + s + "}")
    lines = ["\\begin{tabular}{" + "l" * len(header) + "}", "\\toprule", " & ".join(header) + " \\\\", "\\midrule"]
    lines += [" & ".join(c.replace("±", "$\\pm$") for c in b) + " \\\\" for b in body]
    lines += ["\\bottomrule", "\\end{tabular}"]
    return "\n".join(lines) + "\n"


def csv_text(rows: list[dict]) -> str:
    agg = aggregate(rows)
    buf = io.StringIO()
    w = csv.writer(buf)
    w.writerow(["method", "views", "target"] + [f"{k}_{s}" for k, _, _ in METRICS for s in ("mean", "std")] + ["n"])
    for (m, k, t), vals in sorted(agg.items()):
        n = max((v[2] for v in vals.values()), default=0)
        w.writerow([m, k, t] + [x for key, _, _ in METRICS for x in (vals[key][:2] if key in vals else ("", ""))] + [n])
    return buf.getvalue()
