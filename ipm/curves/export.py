"""A vectorized drawing as SVG (cubic Bezier paths) and as JSON (everything, for a round trip)."""

from __future__ import annotations

import numpy as np

from ipm.curves.settings import Curve, Vectorized
from ipm.errors import InputError

FORMAT = "ipm-vectorized"
VERSION = 1


def _path(beziers: np.ndarray, closed: bool) -> str:
    b = np.asarray(beziers, float)
    if len(b) == 0:
        return ""
    parts = [f"M{b[0, 0, 0]:.3f},{b[0, 0, 1]:.3f}"]
    parts += [f"C{c[1, 0]:.3f},{c[1, 1]:.3f} {c[2, 0]:.3f},{c[2, 1]:.3f} {c[3, 0]:.3f},{c[3, 1]:.3f}" for c in b]
    return " ".join(parts) + (" Z" if closed else "")


def to_svg(v: Vectorized) -> str:
    """SVG text: one path per curve, stroked at twice the half-width with round caps, in pixel
    coordinates (viewBox 0 0 W H)."""
    H, W = v.size
    paths = "\n".join(f'  <path d="{_path(c.beziers, c.closed)}"/>' for c in v.curves if len(c.beziers))
    return (f'<svg xmlns="http://www.w3.org/2000/svg" width="{W}" height="{H}" viewBox="0 0 {W} {H}">\n'
            f'<g fill="none" stroke="black" stroke-width="{2 * v.width:.4f}" stroke-linecap="round" '
            f'stroke-linejoin="round">\n{paths}\n</g>\n</svg>\n')


def to_json(v: Vectorized) -> dict:
    """A JSON-ready dict of everything in ``v``."""
    return {"format": FORMAT, "version": VERSION, "size": [int(v.size[0]), int(v.size[1])],
            "width": float(v.width), "loss": float(v.loss),
            "curves": [{"closed": bool(c.closed), "points": np.round(c.points, 4).tolist(),
                        "beziers": np.round(c.beziers, 4).tolist()} for c in v.curves],
            "junctions": np.asarray(v.junctions, float).reshape(-1, 2).tolist(),
            "endpoints": np.asarray(v.endpoints, float).reshape(-1, 2).tolist()}


def _array(value, shape_tail: tuple[int, ...], what: str) -> np.ndarray:
    try:
        arr = np.asarray(value, dtype=np.float64)
    except (TypeError, ValueError):
        raise InputError(f"vectorized JSON {what}: expected numbers, got {type(value).__name__}") from None
    if arr.size == 0:
        arr = arr.reshape((0, *shape_tail))
    if arr.ndim != 1 + len(shape_tail) or arr.shape[1:] != shape_tail or not np.all(np.isfinite(arr)):
        raise InputError(f"vectorized JSON {what}: expected finite numbers of shape (n, "
                         f"{', '.join(map(str, shape_tail))}), got shape {arr.shape}")
    return arr


def from_json(obj: dict) -> Vectorized:
    """The :class:`Vectorized` of :func:`to_json`'s dict; :class:`InputError` on anything else."""
    if not isinstance(obj, dict) or obj.get("format") != FORMAT:
        raise InputError(f"expected a vectorized drawing (format {FORMAT!r}), got "
                         f"{obj.get('format') if isinstance(obj, dict) else type(obj).__name__!r}")
    if obj.get("version") != VERSION:
        raise InputError(f"vectorized JSON: expected version {VERSION}, got {obj.get('version')!r}")
    try:
        size = tuple(int(x) for x in obj["size"])
        curves = tuple(Curve(points=_array(c["points"], (2,), "points"), closed=bool(c["closed"]),
                             beziers=_array(c["beziers"], (4, 2), "beziers")) for c in obj["curves"])
        width, loss = float(obj["width"]), float(obj["loss"])
    except (KeyError, TypeError, ValueError) as e:
        if isinstance(e, InputError):
            raise
        raise InputError(f"vectorized JSON: expected size, width, loss and curves, got an error ({e})") from None
    if len(size) != 2:
        raise InputError(f"vectorized JSON size: expected (H, W), got {size}")
    return Vectorized(curves=curves, junctions=_array(obj.get("junctions", []), (2,), "junctions"),
                      endpoints=_array(obj.get("endpoints", []), (2,), "endpoints"), width=width, size=size,
                      loss=loss)
