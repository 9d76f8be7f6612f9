"""The layout of the search vector, as pure functions.

A fit searches one normalized vector ``x`` in [0, 1]^m and a dict of discrete values:

    x = [ free generator parameters (normalized by their bounds)              n = len(layout.free)
        | object pose: translation (3), yaw about the up axis, log2 of a uniform scale      5
        | camera (``layout.camera``): elevation, distance, vertical field of view         0 or 3 ]

Three representations of a generator's parameters meet here: the named dict (``{"mug.height": 1.3,
"mug.handle": 1}``), the vectors (continuous ``theta (N,)`` float64 plus a discrete ``dict[str, int]``),
and the normalized vectors (``x (m,)`` above, and the discrete genes ``z (k,)`` in [0, 1] that the
genetic and nlopt searches consume). Every function here converts between two of them and nothing else:
no rendering, no state.
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass

import numpy as np
import torch

from ipm.params import Param, ParamSpec

T_RANGE = 1.5          # translation in normalized units: [-1.5, 1.5]
LOG2S_RANGE = 2.0      # uniform scale in [1/4, 4]
# yaw in [-360, 360] degrees: starts are wrapped into [-180, 180), so a refinement can turn either way
# by half a turn without meeting the bound
YAW_RANGE = 360.0
ELEV = (-10.0, 80.0)   # camera fit: elevation in degrees
DIST = (1.5, 10.0)     # camera fit: distance from the target point
FOV = (10.0, 90.0)     # camera fit: vertical field of view in degrees
DEFAULT_CAMERA = (25.0, 3.2, 40.0)  # (elevation, distance, FOV) of a camera fit's start
POSE_SIZE = 5
CAMERA_SIZE = 3


@dataclass(frozen=True)
class Layout:
    """Where things are in ``x``.

    lo, hi: ``(N,)`` float64 bounds of all the generator's continuous parameters; free: indices of the
    fitted ones (the first ``n`` coordinates of ``x``, in this order); camera: whether the last three
    coordinates are a camera.
    """

    lo: torch.Tensor
    hi: torch.Tensor
    free: tuple[int, ...]
    camera: bool = False

    @staticmethod
    def from_spec(spec: ParamSpec, free: Sequence[str] | None = None, camera: bool = False) -> Layout:
        """The layout of ``spec``'s continuous parameters named in ``free`` (default: all)."""
        cont = [p.name for p in spec.continuous]
        names = cont if free is None else list(free)
        return Layout(spec.lower(), spec.upper(), tuple(cont.index(n) for n in names), camera)

    @property
    def n(self) -> int:
        """Number of generator coordinates."""
        return len(self.free)

    @property
    def m(self) -> int:
        """Length of ``x``."""
        return self.n + POSE_SIZE + (CAMERA_SIZE if self.camera else 0)

    @property
    def pose(self) -> slice:
        """Where the 5 pose coordinates sit in ``x``: right after the ``n`` generator coordinates."""
        return slice(self.n, self.n + POSE_SIZE)


# -- named dict <-> vectors ----------------------------------------------------------------------

def to_vectors(spec: ParamSpec, values: Mapping[str, float]) -> tuple[torch.Tensor, dict[str, int]]:
    """Named dict (validated, defaults filled) -> (``theta (N,)`` float64, discrete values)."""
    return spec.to_vector(values, torch.float64), spec.discrete_values(values)


def from_vectors(spec: ParamSpec, theta: torch.Tensor, discrete: Mapping[str, int]) -> dict[str, float]:
    """``theta (N,)`` and discrete values -> the named dict."""
    return spec.from_vector(theta, discrete)


# -- continuous parameters <-> the first n coordinates of x ---------------------------------------

def normalize(layout: Layout, theta: torch.Tensor) -> torch.Tensor:
    """``theta (N,)`` -> ``u (n,)`` in [0, 1]: the free coordinates over their bounds (clamped)."""
    free = list(layout.free)
    lo, hi = layout.lo[free], layout.hi[free]
    return ((theta[free] - lo) / (hi - lo).clamp(min=1e-12)).clamp(0, 1)


def denormalize(layout: Layout, u: torch.Tensor, theta0: torch.Tensor) -> torch.Tensor:
    """``u (n,)`` -> ``theta (N,)`` of ``u``'s dtype: ``theta0`` with the free coordinates replaced;
    differentiable in ``u``."""
    free = list(layout.free)
    lo, hi = layout.lo[free].to(u.dtype), layout.hi[free].to(u.dtype)
    theta = theta0.to(u.dtype).clone()
    return theta.index_put((torch.as_tensor(free, dtype=torch.long),), lo + u * (hi - lo))


# -- pose and camera ------------------------------------------------------------------------------
# Written with plain arithmetic so that they take floats and tensors alike.

def encode_translation(t):
    """A translation coordinate in normalized units, ``[-T_RANGE, T_RANGE]`` -> [0, 1] (not clamped)."""
    return (t / T_RANGE + 1) / 2


def encode_yaw(yaw_deg):
    """Yaw in degrees, ``[-YAW_RANGE, YAW_RANGE]`` -> [0, 1] (not clamped)."""
    return (yaw_deg / YAW_RANGE + 1) / 2


def encode_log2_scale(log2_scale):
    """``log2`` of the uniform scale, ``[-LOG2S_RANGE, LOG2S_RANGE]`` -> [0, 1] (not clamped)."""
    return (log2_scale / LOG2S_RANGE + 1) / 2


def encode_pose(t: Sequence[float] = (0.0, 0.0, 0.0), yaw: float = 0.0, scale: float = 1.0) -> torch.Tensor:
    """World translation (3), yaw in degrees (wrapped into [-180, 180)) and uniform scale -> ``(5,)``
    float64 in [0, 1] (clamped)."""
    yaw = (yaw + 180.0) % 360.0 - 180.0
    pose = torch.tensor([encode_translation(v) for v in t] + [encode_yaw(yaw), encode_log2_scale(math.log2(scale))],
                        dtype=torch.float64)
    return pose.clamp(0, 1)


def decode_pose(p: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
    """``p (5,)`` -> (translation (3,), yaw in degrees, scale), differentiable."""
    t = (p[:3] * 2 - 1) * T_RANGE
    yaw = (p[3] * 2 - 1) * YAW_RANGE
    scale = torch.pow(2.0, (p[4] * 2 - 1) * LOG2S_RANGE)
    return t, yaw, scale


def encode_camera(camera: Sequence[float] | None = None) -> torch.Tensor:
    """(elevation, distance, FOV) (default :data:`DEFAULT_CAMERA`) -> ``(3,)`` float64 in [0, 1]."""
    elev, dist, fov = camera or DEFAULT_CAMERA
    return torch.tensor([(elev - ELEV[0]) / (ELEV[1] - ELEV[0]), (dist - DIST[0]) / (DIST[1] - DIST[0]),
                         (fov - FOV[0]) / (FOV[1] - FOV[0])], dtype=torch.float64).clamp(0, 1)


def decode_camera(c: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
    """``c (3,)`` -> (elevation, distance, FOV), differentiable."""
    return (ELEV[0] + c[0] * (ELEV[1] - ELEV[0]), DIST[0] + c[1] * (DIST[1] - DIST[0]),
            FOV[0] + c[2] * (FOV[1] - FOV[0]))


# -- the whole vector -----------------------------------------------------------------------------

def encode(layout: Layout, theta: torch.Tensor, *, t: Sequence[float] = (0.0, 0.0, 0.0), yaw: float = 0.0,
           scale: float = 1.0, camera: Sequence[float] | None = None) -> torch.Tensor:
    """``theta (N,)``, pose and camera -> ``x (m,)`` float64 in [0, 1]."""
    parts = [normalize(layout, theta), encode_pose(t, yaw, scale)]
    if layout.camera:
        parts.append(encode_camera(camera))
    return torch.cat(parts)


def decode(layout: Layout, x: torch.Tensor, theta0: torch.Tensor):
    """``x (m,)`` -> (theta (N,), translation (3,), yaw (deg), scale, camera triple or None), all torch,
    differentiable in ``x``; ``theta0`` gives the parameters that are not free."""
    theta = denormalize(layout, x[: layout.n], theta0)
    t, yaw, scale = decode_pose(x[layout.pose])
    cam = decode_camera(x[layout.n + POSE_SIZE:]) if layout.camera else None
    return theta, t, yaw, scale, cam


# -- discrete values <-> genes in [0, 1] ------------------------------------------------------------

def encode_discrete(params: Sequence[Param], discrete: Mapping[str, int]) -> np.ndarray:
    """Values of ``params`` -> ``z (k,)`` float64 in [0, 1] (lo -> 0, hi -> 1)."""
    return np.array([(discrete[p.name] - p.lo) / max(p.hi - p.lo, 1) for p in params], dtype=np.float64)


def decode_discrete(params: Sequence[Param], z: np.ndarray, fixed: Mapping[str, int] | None = None) -> dict:
    """``z (k,)`` -> the nearest values of ``params`` (clipped to their bounds), added to ``fixed``."""
    out = dict(fixed or {})
    for p, v in zip(params, z):
        out[p.name] = int(np.clip(round(p.lo + float(v) * (p.hi - p.lo)), p.lo, p.hi))
    return out
