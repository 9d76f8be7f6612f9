"""Panel building: a multi-storey block of ``sections`` (entrances) built from closed boxes and
prisms, differentiable in all continuous sizes.

Layout (Y up, base at y = 0, centered in X and Z): the block is ``sections * section_width`` long
along X and ``depth`` deep along Z; the main facade faces +Z, the back facade -Z. From the bottom:
a plinth of ``plinth_height``, ``floors`` storeys of ``floor_height``, and a roof of ``roof_height``.

* **walls**: the plinth box, a core box, and on each facade with windows a layer of
  ``wall_thickness`` made of horizontal bands (between the rows of windows) and piers (between
  the windows), which leaves real openings for the windows.
* **windows**: one part per window, filling its opening: a box ``frame_depth`` proud of the facade
  with a pocket (the pane) ``window_inset`` behind the facade surface inside a frame of
  ``frame_width``. ``windows`` per section per floor, evenly spaced, on the front and, with
  ``back_windows``, on the back. A window is ``window_width`` x ``window_height``, its sill
  ``window_sill`` above the floor.
* **balconies**: L-shaped prisms (a slab ``balcony_thickness`` thick under the floor level and a
  front parapet ``balcony_height`` high) ``balcony_depth`` deep and ``balcony_width`` wide, in front of
  windows of floors 1 and up: ``balcony_pattern`` 0 none, 1 all, 2 every other floor, 3 checkerboard.
* **doors**: with ``has_door``, one box per section at its middle, ``door_width`` x ``door_height``,
  standing ``door_depth`` out of the facade (an entrance porch).
* **roof**: ``roof_type`` 0 flat (a slab), 1 gable (a triangular prism, ridge along X), 2 hipped
  (ridge ``roof_ridge`` times the roof's length); it overhangs the walls by ``roof_overhang``.

Sizes are clamped so that every part stays a valid closed solid for every parameter vector:
window width <= 0.9 x the window bay (``section_width / windows``), window height <= 0.85 x the
floor height, sill <= what leaves a lintel of 0.05 x the floor height, frame width <= 0.3 x the
window's smaller side, pane inset <= 0.8 x the wall thickness, balcony width <= the bay, parapet
thickness <= half the balcony depth, door width <= 0.9 x the section width.

Bounding box: x in ``+-(sections * section_width / 2 + roof_overhang)``, y in ``[0, plinth_height +
floors * floor_height + roof_height]``, z from ``-(depth / 2 + max(roof_overhang, frame_depth if
back_windows))`` to ``depth / 2 + max(roof_overhang, frame_depth, balcony_depth if any balcony,
door_depth if has_door)``. Parts are separate closed components (no shared vertices); faces carry
the groups ``walls, windows, balconies, doors, roof``. Counts depend on the discrete values only.
"""

from __future__ import annotations

from collections.abc import Mapping

import numpy as np
import torch

from ipm.errors import InputError
from ipm.generators import _meshkit as mk
from ipm.generators._meshkit import smul
from ipm.generators.base import Generator, register_generator
from ipm.params import Param, ParamSpec, Value
from ipm.types import TriMesh

GROUPS = ("walls", "windows", "balconies", "doors", "roof")
ROOF_TYPES = ("flat", "gable", "hipped")
BALCONY_PATTERNS = ("none", "all", "alternate floors", "checkerboard")

# hipped roof: base loop (counter-clockwise about +Y) then the ridge (+X end, -X end)
_HIP_FACES = ((0, 2, 1), (0, 3, 2), (0, 1, 4), (1, 2, 5), (1, 5, 4), (2, 3, 5), (3, 0, 4), (3, 4, 5))


def _f(name, default, lo, hi, doc="", per=None):
    return Param(name, default, lo, hi, "float", doc, per=per)


def building_spec() -> ParamSpec:
    """The building's parameters: 21 continuous sizes (metres) and 7 discrete counts and switches."""
    return ParamSpec((
        _f("floor_height", 2.8, 2.2, 5.0, "storey height", per="floors"),
        _f("section_width", 16.0, 4.0, 40.0, "length of one section (entrance) along the facade",
           per="sections"),
        _f("depth", 12.0, 4.0, 25.0, "depth of the block"),
        _f("wall_thickness", 0.35, 0.1, 0.8, "thickness of the facade layer around the windows"),
        _f("plinth_height", 0.8, 0.1, 3.0, "height of the plinth below the first floor"),
        _f("window_width", 1.5, 0.3, 4.0, "window opening width"),
        _f("window_height", 1.5, 0.3, 3.0, "window opening height"),
        _f("window_sill", 0.85, 0.05, 1.5, "height of the window opening above the floor"),
        _f("window_inset", 0.15, 0.01, 0.6, "depth of the pane behind the facade surface"),
        _f("frame_width", 0.08, 0.02, 0.3, "window frame width"),
        _f("frame_depth", 0.04, 0.0, 0.3, "how far the window frame stands out of the facade"),
        _f("balcony_width", 3.0, 0.5, 8.0, "balcony width"),
        _f("balcony_depth", 1.1, 0.2, 3.0, "how far a balcony stands out of the facade"),
        _f("balcony_height", 1.0, 0.3, 1.6, "balcony parapet height above the floor"),
        _f("balcony_thickness", 0.15, 0.05, 0.4, "balcony slab and parapet thickness"),
        _f("door_width", 1.6, 0.6, 4.0, "entrance width"),
        _f("door_height", 2.4, 1.8, 4.0, "entrance height"),
        _f("door_depth", 0.6, 0.02, 3.0, "how far the entrance porch stands out of the facade"),
        _f("roof_height", 0.8, 0.1, 10.0, "roof height (slab thickness of a flat roof)"),
        _f("roof_overhang", 0.3, 0.0, 2.0, "roof overhang beyond the walls"),
        _f("roof_ridge", 0.6, 0.05, 0.95, "hipped roof: ridge length as a fraction of the roof length"),
        Param("sections", 4, 1, 10, "int", "number of sections (entrances) along the facade"),
        Param("floors", 5, 1, 30, "int", "number of storeys"),
        Param("windows", 4, 1, 10, "int", "windows per section per floor on a facade"),
        Param("balcony_pattern", 1, 0, 3, "int", "0 none, 1 all, 2 every other floor, 3 checkerboard"),
        Param("roof_type", 0, 0, 2, "int", "0 flat, 1 gable, 2 hipped"),
        Param("has_door", 1, 0, 1, "bool", "an entrance porch per section"),
        Param("back_windows", 1, 0, 1, "bool", "windows on the back facade too"),
    ))


PRESETS: dict[str, dict[str, Value]] = {
    "panel5": {"sections": 4, "floors": 5, "windows": 4, "floor_height": 2.8, "section_width": 16.0,
               "depth": 12.0, "plinth_height": 0.9, "balcony_pattern": 1, "roof_type": 0,
               "roof_height": 0.6, "roof_overhang": 0.15},
    "panel9": {"sections": 3, "floors": 9, "windows": 5, "floor_height": 2.8, "section_width": 18.0,
               "depth": 13.0, "plinth_height": 1.0, "window_width": 1.6, "balcony_pattern": 3,
               "balcony_width": 3.2, "roof_type": 0, "roof_height": 1.0, "roof_overhang": 0.2},
    "house2": {"sections": 1, "floors": 2, "windows": 4, "floor_height": 3.0, "section_width": 10.0,
               "depth": 8.0, "plinth_height": 0.5, "wall_thickness": 0.4, "window_width": 1.2,
               "window_height": 1.4, "balcony_pattern": 0, "roof_type": 1, "roof_height": 3.5,
               "roof_overhang": 0.5, "door_width": 1.2, "door_height": 2.2, "door_depth": 0.3},
    "tower": {"sections": 1, "floors": 16, "windows": 4, "floor_height": 3.0, "section_width": 16.0,
              "depth": 16.0, "plinth_height": 1.2, "balcony_pattern": 2, "balcony_width": 2.8,
              "roof_type": 2, "roof_height": 2.5, "roof_ridge": 0.2, "roof_overhang": 0.4},
}


def _boxes(x, y, z) -> tuple[torch.Tensor, torch.Tensor]:
    """Box corners from per-axis ``(lo, hi)`` pairs of broadcastable tensors: ``lo, hi: (B, 3)``."""
    lo = torch.stack(torch.broadcast_tensors(x[0], y[0], z[0]), -1).reshape(-1, 3)
    hi = torch.stack(torch.broadcast_tensors(x[1], y[1], z[1]), -1).reshape(-1, 3)
    return lo, hi


def _rot180(v: torch.Tensor) -> torch.Tensor:
    """Rotate points ``(N, 3)`` half a turn about Y (keeps the faces' orientation)."""
    x, y, z = v.unbind(-1)
    return torch.stack([-x, y, -z], -1)


class BuildingGenerator(Generator):
    """Panel buildings (see the module docstring). ``lod`` is accepted and ignored: every part is
    already its exact box or prism."""

    name = "building"
    kind = "mesh"
    description = "multi-storey panel block: walls with window openings, windows, balconies, doors, roof"
    parts = GROUPS

    def __init__(self):
        self.spec = building_spec()
        self.presets = PRESETS
        self._names = [p.name for p in self.spec.continuous]
        self._topologies: dict[tuple, mk.Topology] = {}

    def _discrete(self, discrete: Mapping[str, int]) -> dict[str, int]:
        out = {}
        for prm in self.spec.discrete:
            out[prm.name] = prm.check(discrete.get(prm.name, prm.default))
        return out

    def mesh(self, theta: torch.Tensor, discrete: Mapping[str, int], lod=None) -> TriMesh:
        """The building for ``theta: (21,) float`` (vertices differentiable in it) and the discrete
        values (defaults where absent). Groups: walls, windows, balconies, doors, roof."""
        n = len(self._names)
        if theta.ndim != 1 or theta.shape[0] != n:
            raise InputError(f"theta: expected shape ({n},), got {tuple(theta.shape)}")
        d = self._discrete(discrete)
        p = dict(zip(self._names, theta.split(1)))
        S, F, W = d["sections"], d["floors"], d["windows"]
        N = S * W                                                    # windows per floor and facade
        fh, sw, D, wt = p["floor_height"], p["section_width"], p["depth"], p["wall_thickness"]
        P = p["plinth_height"]
        hx, hz = smul(sw, 0.5 * S), smul(D, 0.5)
        T = P + smul(fh, float(F))                                   # top of the walls
        bay = smul(sw, 1.0 / W)
        ww = torch.minimum(p["window_width"], smul(bay, 0.9))
        wh = torch.minimum(p["window_height"], smul(fh, 0.85))
        sill = torch.minimum(p["window_sill"], smul(fh, 0.95) - wh)
        cx = mk.const(mk.half_steps, N, like=theta) * bay - hx                        # (N,) window centers
        yf = P + mk.const(mk.steps, 0, F, like=theta) * fh                             # (F,) floor levels
        wb = yf + sill                                                                 # window bottoms
        wtop = wb + wh
        hw = smul(ww, 0.5)
        x0, x1 = cx - hw, cx + hw
        facades = (1, -1) if d["back_windows"] else (1,)

        # walls: plinth, core, and per facade the bands and piers around the openings
        zero = torch.zeros_like(P)
        z_core_back = -(hz - wt) if d["back_windows"] else -hz
        wall = [_boxes((-hx, hx), (zero, P), (-hz, hz)), _boxes((-hx, hx), (P, T), (z_core_back, hz - wt))]
        band_y = (torch.cat([P, wtop]), torch.cat([wb, T]))                           # (F + 1,)
        pier_x = (torch.cat([-hx, x1]), torch.cat([x0, hx]))                          # (N + 1,)
        for side in facades:
            z = (hz - wt, hz) if side > 0 else (-hz, wt - hz)
            wall.append(_boxes((-hx, hx), band_y, z))
            wall.append(_boxes((pier_x[0][None, :], pier_x[1][None, :]), (wb[:, None], wtop[:, None]), z))
        lo, hi = (torch.cat(t) for t in zip(*wall))
        wall_v = mk.box_verts(lo, hi)
        n_wall = lo.shape[0]

        # windows: a box with a pocket, loops back -> front outer -> front inner -> pane (about +Z)
        fw = torch.minimum(p["frame_width"], smul(torch.minimum(ww, wh), 0.3))
        inset = torch.minimum(p["window_inset"], smul(wt, 0.8))
        ox = torch.stack([x1, x1, x0, x0], -1)[None].expand(F, -1, -1)                # (F, N, 4)
        ix = torch.stack([x1 - fw, x1 - fw, x0 + fw, x0 + fw], -1)[None].expand(F, -1, -1)
        oy = torch.stack([wb, wtop, wtop, wb], -1)[:, None].expand(-1, N, -1)
        iy = torch.stack([wb + fw, wtop - fw, wtop - fw, wb + fw], -1)[:, None].expand(-1, N, -1)
        zs = torch.cat([hz - wt, hz + p["frame_depth"], hz + p["frame_depth"], hz - inset])   # (4,)
        X = torch.stack([ox, ox, ix, ix], 2)                                           # (F, N, 4, 4)
        Y = torch.stack([oy, oy, iy, iy], 2)
        Z = zs[:, None].expand(4, 4).expand(F, N, 4, 4)
        win_front = torch.stack([X, Y, Z], -1).reshape(-1, 3)
        win_v = [win_front] + ([_rot180(win_front)] if d["back_windows"] else [])
        n_win = F * N * len(facades)

        # balconies: L-shaped prisms along +X, loop (y, z) counter-clockwise about +X starting at the
        # parapet's inner corner so that the caps can fan from it
        I, J = _balcony_slots(F, N, W, d["balcony_pattern"])
        n_bal = len(I)
        bal_v = []
        if n_bal:
            I_t, J_t = torch.as_tensor(I), torch.as_tensor(J)
            bd = p["balcony_depth"]
            half = smul(torch.minimum(p["balcony_width"], bay), 0.5)
            bt = p["balcony_thickness"]
            pt = torch.minimum(bt, smul(bd, 0.5))
            y0 = yf[I_t]                                                              # (B,)
            c = cx[J_t]
            zb, zf = hz - smul(wt, 0.5), hz + bd
            zi = zf - pt
            top, bottom = y0 + p["balcony_height"], y0 - bt
            Yl = torch.stack([y0, top, top, bottom, bottom, y0], -1)
            Zl = torch.cat([zi, zi, zf, zf, zb, zb])[None].expand(n_bal, -1)
            Xl = torch.stack([c - half, c + half], -1)                                # (B, 2)
            bal_v.append(torch.stack([Xl[:, :, None].expand(-1, -1, 6), Yl[:, None].expand(-1, 2, -1),
                                      Zl[:, None].expand(-1, 2, -1)], -1).reshape(-1, 3))

        # doors: one porch box per section
        n_door = S if d["has_door"] else 0
        door_v = []
        if n_door:
            sc = mk.const(mk.half_steps, S, like=theta) * sw - hx
            dw = smul(torch.minimum(p["door_width"], smul(sw, 0.9)), 0.5)
            lo, hi = _boxes((sc - dw, sc + dw), (zero, p["door_height"]),
                            (hz - smul(wt, 0.5), hz + p["door_depth"]))
            door_v.append(mk.box_verts(lo, hi))

        # roof
        ov = p["roof_overhang"]
        roof_v = ROOFS[d["roof_type"]][0](hx + ov, hz + ov, T, T + p["roof_height"], p)

        verts = [wall_v, *win_v, *bal_v, *door_v, roof_v]
        return self._topology(n_wall, n_win, n_bal, n_door, d["roof_type"]).mesh(verts)

    def _topology(self, n_wall: int, n_win: int, n_bal: int, n_door: int, roof_type: int) -> mk.Topology:
        key = (n_wall, n_win, n_bal, n_door, roof_type)
        if key not in self._topologies:
            roof_f = ROOFS[roof_type][1]()
            faces = [mk.repeat_faces_np(None, 8, n_wall, 2, 4), mk.repeat_faces_np(None, 16, n_win, 4, 4),
                     mk.repeat_faces_np(None, 12, n_bal, 2, 6), mk.repeat_faces_np(None, 8, n_door, 2, 4),
                     roof_f]
            counts = [8 * n_wall, 16 * n_win, 12 * n_bal, 8 * n_door, int(roof_f.max()) + 1]
            self._topologies[key] = mk.Topology.build(faces, counts, list(GROUPS))
        return self._topologies[key]

    def to_mesh(self, values: Mapping[str, Value], *, resolution: int | None = None, lod=None) -> TriMesh:
        """The mesh of a (validated) value dict (``resolution`` and ``lod`` do not apply)."""
        theta, discrete = self.split(self.spec.validate(values))
        return self.mesh(theta, discrete, lod).detach()

    def counts(self, discrete: Mapping[str, int]) -> dict[str, int]:
        """Parts per group for these discrete values (without building)."""
        d = self._discrete(discrete)
        S, F, W = d["sections"], d["floors"], d["windows"]
        n_fac = 1 + d["back_windows"]
        walls = 2 + n_fac * ((F + 1) + F * (S * W + 1))
        return {"walls": walls, "windows": S * F * W * n_fac,
                "balconies": len(_balcony_slots(F, S * W, W, d["balcony_pattern"])[0]),
                "doors": S * d["has_door"], "roof": 1}

    def extent(self, values: Mapping[str, Value]) -> tuple[list[float], list[float]]:
        """The documented bounding box ``(lo [x, y, z], hi [x, y, z])`` of a value dict."""
        v = self.spec.validate(values)
        hx = v["sections"] * v["section_width"] / 2 + v["roof_overhang"]
        top = v["plinth_height"] + v["floors"] * v["floor_height"] + v["roof_height"]
        hz = v["depth"] / 2
        has_bal = bool(self.counts(v)["balconies"])
        front = max(v["roof_overhang"], v["frame_depth"], v["balcony_depth"] if has_bal else 0.0,
                    v["door_depth"] if v["has_door"] else 0.0)
        back = max(v["roof_overhang"], v["frame_depth"] if v["back_windows"] else 0.0)
        return [-hx, 0.0, -(hz + back)], [hx, top, hz + front]


def _flat_roof(rx, rz, base, top, p):
    """A slab: one box."""
    return mk.box_verts(*_boxes((-rx, rx), (base, top), (-rz, rz)))


def _gable_roof(rx, rz, base, top, p):
    """A triangular prism along X: the loop (front eave, back eave, ridge) runs counter-clockwise
    about +X and is extruded from -rx to +rx."""
    zero = torch.zeros_like(rz)
    x = torch.cat([-rx, -rx, -rx, rx, rx, rx])
    y = torch.cat([base, base, top]).repeat(2)
    z = torch.cat([rz, -rz, zero]).repeat(2)
    return torch.stack([x, y, z], -1)


def _hipped_roof(rx, rz, base, top, p):
    """The base rectangle (counter-clockwise about +Y) and a ridge along X, ``roof_ridge`` of the
    roof's length."""
    zero = torch.zeros_like(rz)
    ridge = rx * p["roof_ridge"]
    x = torch.cat([rx, rx, -rx, -rx, ridge, -ridge])
    y = torch.cat([base, base, base, base, top, top])
    z = torch.cat([rz, -rz, -rz, rz, zero, zero])
    return torch.stack([x, y, z], -1)


# roof_type -> (vertices from (rx, rz, base, top, params), faces (NumPy))
ROOFS = {
    0: (_flat_roof, lambda: mk.repeat_faces_np(None, 8, 1, 2, 4)),
    1: (_gable_roof, lambda: mk.loft_faces_np(2, 3, "fan", "fan")),
    2: (_hipped_roof, lambda: np.asarray(_HIP_FACES, dtype=np.int64)),
}

BALCONY_SLOTS = {                       # balcony_pattern -> keep(floor, window)
    0: lambda i, j: False,
    1: lambda i, j: True,
    2: lambda i, j: i % 2 == 1,
    3: lambda i, j: (i + j) % 2 == 1,
}


def _balcony_slots(F: int, N: int, W: int, pattern: int) -> tuple[list[int], list[int]]:
    """(floor, window) indices of the balconies on the front facade, by pattern (floors >= 1)."""
    keep = BALCONY_SLOTS[pattern]
    slots = [(i, j) for i in range(1, F) for j in range(N) if keep(i, j)]
    return [s[0] for s in slots], [s[1] for s in slots]


@register_generator("building")
def _building() -> BuildingGenerator:
    return BuildingGenerator()
