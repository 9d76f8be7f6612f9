"""Generators written as one function: the base classes of plug-ins (``ipm --plugin my_gen.py``).

A user's generator is a list of parameters and one differentiable function. :class:`MeshGenerator` takes
``build(p) -> (verts, faces)`` (or a :class:`~ipm.types.TriMesh` with face groups); :class:`SdfGenerator`
takes ``distance(p, points) -> (...)`` and ``bounds(p)``. In both, ``p`` maps every parameter's name to
its value: a 0-d tensor for a continuous parameter (a view of ``theta``, so that everything built from it
is differentiable in ``theta``) and a Python ``int`` for a discrete one. Everything else (checks, Jacobians,
previews, fits, run folders, the bench) is the :class:`~ipm.generators.base.Generator` machinery, which these
classes fill in::

    class Slab(MeshGenerator):
        name = "slab"
        params = (Param("width", 1.0, 0.2, 3.0), Param("notches", 2, 0, 8, "int"))

        def build(self, p):
            ...  # vertices from p["width"] (a tensor), faces from p["notches"] (an int)
            return verts, faces

The results are checked where they leave the user's code: shapes and dtypes (:func:`mesh_from_build`,
:func:`check_distances`), with one line naming the generator and what was expected.
"""

from __future__ import annotations

import inspect
from abc import abstractmethod
from collections.abc import Mapping, Sequence
from typing import Any

import numpy as np
import torch

from ipm.errors import InputError
from ipm.generators.base import Generator, ValuesField, check_field_meshing
from ipm.params import Param, ParamSpec, Value
from ipm.types import TriMesh

__all__ = ["MeshGenerator", "Param", "SdfGenerator"]


def named(spec: ParamSpec, theta: torch.Tensor, discrete: Mapping[str, int]) -> dict[str, Any]:
    """``p`` of a user's function: each continuous parameter as ``theta[i]`` (0-d, differentiable), each discrete
    one as an ``int`` (defaults where ``discrete`` lacks it)."""
    p: dict[str, Any] = {par.name: theta[i] for i, par in enumerate(spec.continuous)}
    for par in spec.discrete:
        p[par.name] = int(discrete.get(par.name, par.default))
    return p


def where(obj: object) -> str:
    """``name (file)`` of a user's generator, for messages."""
    try:
        src = inspect.getsourcefile(type(obj))
    except TypeError:
        src = None
    return f"{getattr(obj, 'name', '?')} ({src})" if src else str(getattr(obj, "name", "?"))


def _spec(gen: Generator) -> ParamSpec:
    """The spec of a class's ``params`` (a list of :class:`Param`), refused with one line if it is not one."""
    params = getattr(gen, "params", ())
    if not isinstance(params, Sequence) or not all(isinstance(p, Param) for p in params):
        raise InputError(f"{where(gen)}: params must be a list of ipm Param, got {type(params).__name__}")
    return ParamSpec(tuple(params))


def mesh_from_build(gen: Generator, out: object, dtype: torch.dtype) -> TriMesh:
    """The :class:`TriMesh` of what ``build`` returned: ``(verts (V, 3) float tensor, faces (F, 3) int)`` or a
    TriMesh; anything else refused with one line naming the generator."""
    if isinstance(out, TriMesh):
        verts, faces, groups, names = out.verts, out.faces, out.groups, out.group_names
    elif isinstance(out, tuple) and len(out) == 2:
        (verts, faces), groups, names = out, None, ()
    else:
        raise InputError(f"{where(gen)}: build() must return (verts, faces) or a TriMesh, got {type(out).__name__}")
    if not torch.is_tensor(verts) or not verts.is_floating_point():
        raise InputError(f"{where(gen)}: build()'s vertices must be a float torch tensor made from p's tensors, "
                         f"got {type(verts).__name__}")
    if verts.ndim != 2 or verts.shape[-1] != 3:
        raise InputError(f"{where(gen)}: build()'s vertices: expected shape (V, 3), got {tuple(verts.shape)}")
    faces = torch.as_tensor(faces, device=verts.device)
    if faces.ndim != 2 or faces.shape[-1] != 3 or faces.is_floating_point() or faces.shape[0] == 0:
        raise InputError(f"{where(gen)}: build()'s faces: expected (F, 3) integers with F > 0, got "
                         f"{tuple(faces.shape)} {str(faces.dtype).replace('torch.', '')}")
    faces = faces.to(torch.int64)
    if int(faces.min()) < 0 or int(faces.max()) >= verts.shape[0]:
        raise InputError(f"{where(gen)}: build()'s faces index vertices {int(faces.min())}..{int(faces.max())}, "
                         f"but there are {verts.shape[0]}")
    return TriMesh(verts.to(dtype), faces, groups, tuple(names))


def check_distances(gen: Generator, d: object, points: torch.Tensor) -> torch.Tensor:
    """``distance``'s result, refused unless it is a float tensor of shape ``points.shape[:-1]``."""
    if not torch.is_tensor(d) or not d.is_floating_point() or d.shape != points.shape[:-1]:
        got = tuple(d.shape) if torch.is_tensor(d) else type(d).__name__
        raise InputError(f"{where(gen)}: distance() must return a float tensor of shape {tuple(points.shape[:-1])} "
                         f"(one value per point), got {got}")
    return d


class MeshGenerator(Generator):
    """Base of a mesh generator written as ``build(p) -> (verts, faces)`` (module docstring). Subclasses set
    ``name``, ``params`` and optionally ``presets``, ``description`` and ``parts``."""

    kind = "mesh"
    params: Sequence[Param] = ()

    def __init__(self) -> None:
        self.spec = _spec(self)

    @abstractmethod
    def build(self, p: Mapping[str, Any]) -> tuple[torch.Tensor, Any] | TriMesh:
        """``(verts (V, 3) float, differentiable in p's tensors; faces (F, 3) int, counter-clockwise from
        outside)`` for the values ``p``; faces may depend on the discrete values only."""

    def mesh(self, theta: torch.Tensor, discrete: Mapping[str, int], lod: Any = None) -> TriMesh:
        """The mesh at ``theta (n,)`` and ``discrete`` (``lod`` is not used)."""
        return mesh_from_build(self, self.build(named(self.spec, theta, discrete)), theta.dtype)

    def to_mesh(self, values: Mapping[str, Value], *, resolution: int | None = None, lod: Any = None) -> TriMesh:
        """The mesh at ``values``, cut from autograd (``resolution`` is not used: the mesh is the function's)."""
        theta, discrete = self.split(self.values(overrides=values))
        return self.mesh(theta, discrete).detach()


class _Field(ValuesField):
    """An :class:`SdfGenerator`'s field at stored values: what fits, renders and Jacobians of SDF generators
    use (``sdf``, ``with_theta``, ``bounds``)."""

    def _eval(self, theta: torch.Tensor, points: torch.Tensor) -> torch.Tensor:
        return self.gen.sdf(theta, points, self.spec.discrete_values(self._values))

    def bounds(self) -> tuple[np.ndarray, np.ndarray]:
        """The generator's ``bounds(p)`` at the stored values, as two (3,) float64 arrays with lo < hi."""
        gen = self.gen
        p = named(self.spec, self.theta(), self.spec.discrete_values(self._values))
        try:
            lo, hi = (np.asarray([float(c) for c in b], dtype=np.float64) for b in gen.bounds(p))
        except (TypeError, ValueError):
            raise InputError(f"{where(gen)}: bounds() must return (lo, hi), each three numbers") from None
        if lo.shape != (3,) or hi.shape != (3,) or not np.all(np.isfinite(lo) & np.isfinite(hi) & (lo < hi)):
            raise InputError(f"{where(gen)}: bounds() must return finite (lo, hi), three numbers each, lo < hi; "
                             f"got {lo.tolist()}, {hi.tolist()}")
        return lo, hi


class SdfGenerator(Generator):
    """Base of an SDF generator written as ``distance(p, points)`` and ``bounds(p)`` (module docstring).
    Subclasses set ``name``, ``params`` and optionally ``presets`` and ``description``."""

    kind = "sdf"
    params: Sequence[Param] = ()

    def __init__(self) -> None:
        self.spec = _spec(self)

    @abstractmethod
    def distance(self, p: Mapping[str, Any], points: torch.Tensor) -> torch.Tensor:
        """Signed distances ``(...)`` at ``points (..., 3)``, negative inside, differentiable in p's tensors."""

    @abstractmethod
    def bounds(self, p: Mapping[str, Any]) -> tuple[Sequence[float], Sequence[float]]:
        """A box ``(lo, hi)`` (three numbers each) that holds the surface at the values ``p``."""

    def sdf(self, theta: torch.Tensor, points: torch.Tensor, discrete: Mapping[str, int] | None = None):
        """Distances ``(...)`` at ``points (..., 3)`` for ``theta (n,)`` and ``discrete``."""
        return check_distances(self, self.distance(named(self.spec, theta, discrete or {}), points), points)

    def tree_for(self, discrete: Mapping[str, int] | None = None) -> _Field:
        """The field with these discrete values (defaults for the rest)."""
        return _Field(self, {**self.spec.defaults(), **(discrete or {})})

    def check_meshing(self, values: Mapping[str, Value], resolution: int) -> None:
        """Marching cubes over ``bounds``: the grid must fit in memory (:func:`check_field_meshing`)."""
        check_field_meshing(self.tree_for(), values, resolution)

    def to_mesh(self, values: Mapping[str, Value], *, resolution: int | None = None, lod: Any = None) -> TriMesh:
        """Marching cubes over ``bounds``, ``resolution`` (default 128) samples along the longest side."""
        from ipm.sdf.meshing import mesh_sdf

        field = self.tree_for().with_values(values)
        lo, hi = field.bounds()
        return mesh_sdf(lambda pts: field.sdf(None, pts), lo, hi, resolution or 128)
