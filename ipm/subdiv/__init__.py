"""Subdivision of triangle meshes that stays differentiable in torch (issue #14).

A scheme (registered by name in :data:`SCHEMES`, one module in :mod:`ipm.subdiv.schemes` each) turns
``(verts (V, 3), faces (F, 3))`` into a finer mesh, ``levels`` times. The classic schemes are linear:
the new vertices are ``S @ verts`` for a sparse matrix ``S`` that depends on the faces only (libigl's
``loop_matrix`` and ``upsample_matrix``), applied through :func:`ipm.subdiv.sparse.sparse_apply` so that
gradients flow back as ``S^T g`` and the Jacobian of a subdivided generator mesh is ``S J``.
"""

from __future__ import annotations

from ipm.registry import Registry
from ipm.subdiv.linear import LinearScheme, Scheme, check_levels, clean, subdivide

SCHEMES: Registry[Scheme] = Registry("subdivision scheme", ["ipm.subdiv.schemes"])

__all__ = ["SCHEMES", "LinearScheme", "Scheme", "check_levels", "clean", "subdivide"]
