"""Conversions of a mesh into the universal representations: ``bsp`` (a union of convex polytopes,
:mod:`ipm.convert.bsp`), ``perturb`` (a quadric plus perturbation functions, :mod:`ipm.convert.perturb`)
and ``sdftree`` (the BSP fit written as an SDF node tree, :mod:`ipm.convert.sdftree`).

Every converter is ``fn(mesh, *, progress=None, seed=0, **options) -> Conversion``; its result holds a
generator, the converted values and the JSON document that ``get_generator(path)`` and
``ipm generate path`` load back. Converters register themselves by name in :data:`CONVERTERS`
(``@CONVERTERS.register("name")``; a new one is one new module in this package), found on first lookup, so
``ipm --help`` does not import them.
"""

from __future__ import annotations

from collections.abc import Callable

from ipm.errors import InputError
from ipm.registry import Registry

CONVERTERS: Registry[Callable] = Registry("conversion target", packages=["ipm.convert"])


def get_converter(name: str) -> Callable:
    """The converter registered as ``name``; ``InputError`` lists the known ones."""
    if name not in CONVERTERS:
        raise InputError(f"unknown conversion target {name!r}; expected one of {', '.join(CONVERTERS)}")
    return CONVERTERS.get(name)


def convert(mesh, to: str, **options):
    """Convert ``mesh`` (TriMesh, trimesh or (V, F)) to the representation ``to``; see each converter
    for ``options``. Returns a :class:`~ipm.convert.common.Conversion`."""
    return get_converter(to)(mesh, **options)


def check_mesh_resolution(resolution) -> int:
    """The meshing resolution of a converted shape, refused (:class:`InputError`, with the limit) when its
    grid would not fit in memory: see :func:`ipm.convert.common.check_mesh_resolution`."""
    from ipm.convert.common import check_mesh_resolution as check

    return check(resolution)


__all__ = ["CONVERTERS", "check_mesh_resolution", "convert", "get_converter"]
