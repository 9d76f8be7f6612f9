"""The objective of a fit as a sum of small terms, one module each, registered by name in :data:`TERMS`.

A term is a class with a ``name``, an ``order`` (its place in the sum: the sum is taken in this order, so
the loss does not depend on which module was found first), ``applies(problem) -> bool`` (whether the fit has
what it measures: a mesh target, depth maps, a prior weight, ...) and ``__call__(ev) -> 0-dim tensor``,
given an :class:`Evaluation` (the point, the phase, and what the terms of one evaluation share: the posed
shape, the cameras, the soft silhouettes, one exact raster per view). A term may add to ``ev.extras``, which
the evaluator records (per-view IoU, pixels the tie rule compares, the solved light). A phase of the fit
(:class:`~ipm.optim.phases.Phase`) may leave terms out by name (the outline leaves out ``parts``).

Adding a term is one new module in this package with ``@TERMS.register()`` on its class.
"""

from __future__ import annotations

from collections.abc import Mapping
from functools import cached_property

import torch

from ipm.optim.phases import Phase
from ipm.optim.shapes import Pose
from ipm.optim.targets import MaskTarget
from ipm.registry import Registry

TERMS = Registry("loss term", packages=["ipm.optim.terms"])


class Evaluation:
    """One evaluation of the objective of ``prob`` (an :class:`ipm.optim.problem.Problem`, which builds its
    terms on this module): ``x (m,)`` (a leaf that requires grad when ``need_grad``), the
    discrete values (the starting ones where absent), the phase, and what its terms share, each made once
    on first use."""

    def __init__(self, prob, x: torch.Tensor, discrete: Mapping[str, int], phase: Phase, need_grad: bool):
        self.prob, self.x, self.phase, self.need_grad = prob, x, phase, need_grad
        self.discrete = dict(discrete)
        self.full = {**prob.d0, **discrete}
        self.extras: dict = {}
        self._rasters: dict[int, object] = {}
        self._views: dict[int, object] = {}

    def _theta_pose(self, x: torch.Tensor) -> tuple[torch.Tensor, Pose]:
        theta, t, yaw, scale, _ = self.prob.decode(x)
        c0, size = self.prob.frame(self.full)
        return self.prob.carry(theta, self.full), Pose(t, yaw, scale, c0, size)

    @cached_property
    def theta(self) -> torch.Tensor:
        """The generator's continuous values ``(N,)`` (counts carried: :meth:`Problem.carry`)."""
        return self._theta_pose(self.x)[0]

    @cached_property
    def pose(self) -> Pose:
        return self._theta_pose(self.x)[1]

    @cached_property
    def cameras(self) -> list:
        """The views' cameras (fitted ones follow ``x``), shared by the cue terms."""
        return self.prob.cameras(self.x)

    def own_cameras(self) -> list:
        """The cameras made anew, for a term whose gradient should reach ``x`` by its own path (the sum of the
        paths' gradients is then taken in the same order as it always was, bit for bit)."""
        return self.prob.cameras(self.x)

    @cached_property
    def mesh(self):
        """The posed mesh (None for a shape without faces, whose silhouettes need none)."""
        if not self.prob.shape.has_faces:
            return None
        return self.prob.shape.world_mesh(self.theta, self.full, self.pose)

    @cached_property
    def still_mesh(self):
        """The posed mesh with the pose (and camera) held: what part labels move (only the shape)."""
        if not self.need_grad:
            return self.mesh
        n = self.prob.n
        theta, pose = self._theta_pose(torch.cat([self.x[:n], self.x[n:].detach()]))
        return self.prob.shape.world_mesh(theta, self.full, pose)

    @cached_property
    def silhouettes(self) -> torch.Tensor:
        """Soft silhouettes ``(K, H, W)`` at the phase's blur."""
        return self.prob.shape.silhouettes(self.theta, self.full, self.pose, self.own_cameras(), self.phase.sigma,
                                           self.mesh)

    def view_camera(self, i: int):
        """Camera ``i`` of :attr:`cameras` in the mesh's dtype, shared by the cue terms."""
        if i not in self._views:
            self._views[i] = self.cameras[i].to(self.mesh.verts.dtype)
        return self._views[i]

    def raster(self, i: int):
        """The exact raster of view ``i`` (:func:`ipm.render.deferred.rasterize`), shared by the cue terms."""
        if i not in self._rasters:
            from ipm.render import deferred as R

            self._rasters[i] = R.rasterize(self.mesh.verts, self.mesh.faces, self.view_camera(i))
        return self._rasters[i]


    def view_mean(self, weight: float, record: str, view_loss) -> torch.Tensor:
        """``weight`` times the mean over the views of ``view_loss(i, raster) -> (loss, kept)``, summed in view
        order; each view's ``kept`` (a measurement the evaluator records) appended to ``extras[record]``."""
        K = len(self.cameras)
        total = self.mesh.verts.sum() * 0.0
        self.extras[record] = []
        for i in range(K):
            loss, kept = view_loss(i, self.raster(i))
            total = total + weight / K * loss
            self.extras[record].append(kept)
        return total


class ViewCue:
    """Base of the terms that compare one cue of a mask target view by view (depth, part labels, a grey
    photo): such a term applies where the target carries its ``cue`` (an attribute of
    :class:`~ipm.optim.targets.MaskTarget`)."""

    cue = ""

    def applies(self, prob) -> bool:
        """Whether the target is a mask target that carries this term's cue."""
        return isinstance(prob.target, MaskTarget) and getattr(prob.target, self.cue) is not None


def active_terms(prob) -> list:
    """The terms that apply to ``prob``, in their order."""
    terms = [cls() for _, cls in TERMS.items()]
    return sorted((t for t in terms if t.applies(prob)), key=lambda t: (t.order, t.name))
