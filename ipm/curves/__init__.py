"""2D curve networks as the zero set of a piecewise bicubic implicit function, fitted to a raster drawing
(``ipm vectorize``).

A drawing's ink (H, W) in [0, 1] is modelled as exp(-p(x, y)^2 / w^2), p piecewise bicubic Hermite on a
grid of square cells, each cell with its own copy of its corner data and a soft continuity between the
copies (:mod:`ipm.curves.hermite`). p starts as signed distances to the ink's centreline
(:mod:`ipm.curves.init`), is fitted by Adam (:mod:`ipm.curves.fit`), and its zero set is traced, checked
against the ink, joined into curves with junctions and endpoints (:mod:`ipm.curves.extract`) and fitted by
cubic Beziers (:mod:`ipm.curves.bezier`).
"""

from ipm.curves.export import from_json, to_json, to_svg
from ipm.curves.settings import Curve, Vectorized, VectorizeSettings
from ipm.curves.strokes import render_strokes
from ipm.curves.vectorize import vectorize

__all__ = ["Curve", "Vectorized", "VectorizeSettings", "from_json", "render_strokes", "to_json", "to_svg",
           "vectorize"]
