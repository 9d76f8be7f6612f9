"""``shading``: the rendered normals shaded by the light that best explains the grey photo on the object's
pixels, solved in closed form per view (:func:`ipm.losses.cues.shading_loss`), ``FitSettings.image_weight``
averaged over the views; records the light (``light``)."""

from __future__ import annotations

import torch

from ipm.losses import cues as C
from ipm.optim.terms import TERMS, Evaluation, ViewCue


@TERMS.register()
class Shading(ViewCue):
    """The rendered normals, shaded by the best light, against the grey photo."""

    name = "shading"
    cue = "image"
    order = 32

    def __call__(self, ev: Evaluation) -> torch.Tensor:
        from ipm.render import deferred as R

        t, v, f = ev.prob.target, ev.mesh.verts, ev.mesh.faces

        def view(i: int, rast):
            normal = R.vertex_normal_image(v, f, rast)
            return C.shading_loss(normal, t.image[i].to(v.dtype), rast.mask & (t.masks[i] > 0.5))

        return ev.view_mean(ev.prob.s.image_weight, "light", view)
