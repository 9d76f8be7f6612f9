"""``depth``: the rendered depth against the target's depth maps (:func:`ipm.losses.cues.depth_loss`, in units
of each view's depth scale), ``FitSettings.depth_weight`` averaged over the views; records the object pixels
whose depth agrees (``depth_px``, what the tie rule compares)."""

from __future__ import annotations

import torch

from ipm.losses import cues as C
from ipm.optim.terms import TERMS, Evaluation, ViewCue


@TERMS.register()
class Depth(ViewCue):
    """The rendered depth against the target's depth maps."""

    name = "depth"
    cue = "depth"
    order = 30

    def __call__(self, ev: Evaluation) -> torch.Tensor:
        from ipm.render import deferred as R

        t, v, f = ev.prob.target, ev.mesh.verts, ev.mesh.faces

        def view(i: int, rast):
            obj = t.masks[i] > 0.5
            d = R.depth(v, f, ev.view_camera(i), rast)
            tgt = t.depth[i].to(d.dtype)
            loss = C.depth_loss(d, rast.mask, tgt, obj, ev.prob.depth_scales[i])
            with torch.no_grad():
                return loss, C.depth_agreement(d, rast.mask, tgt, obj, ev.prob.depth_scales[i])

        return ev.view_mean(ev.prob.s.depth_weight, "depth_px", view)
