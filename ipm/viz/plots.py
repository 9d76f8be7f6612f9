"""Loss curves (matplotlib, Agg backend, imported only here and only when called)."""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from pathlib import Path

from ipm.errors import InputError


def plot_losses(curves: Mapping[str, Sequence[float]] | Sequence[float], path: str | Path, *,
                title: str = "loss", log_y: bool = True, xlabel: str = "evaluation") -> Path:
    """Plot one or several loss curves and write a PNG atomically; returns the path."""
    import matplotlib

    matplotlib.use("Agg", force=False)
    import matplotlib.pyplot as plt

    from ipm.files import atomic_path

    if not isinstance(curves, Mapping):
        curves = {"loss": curves}
    if not curves or all(len(v) == 0 for v in curves.values()):
        raise InputError("plot_losses: expected at least one non-empty curve, got none")
    fig, ax = plt.subplots(figsize=(6, 4), dpi=100)
    try:
        for name, ys in curves.items():
            ax.plot(range(len(ys)), [float(y) for y in ys], label=name)
        if log_y and all(float(y) > 0 for ys in curves.values() for y in ys):
            ax.set_yscale("log")
        ax.set_xlabel(xlabel)
        ax.set_title(title)
        if len(curves) > 1:
            ax.legend()
        ax.grid(alpha=0.3)
        fig.tight_layout()
        with atomic_path(path) as tmp:
            fig.savefig(tmp, format="png")
    finally:
        plt.close(fig)
    return Path(path)
