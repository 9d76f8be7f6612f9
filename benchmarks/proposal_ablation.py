"""What keeps the proposal alone below issue #29's bars: the guess with one of its parts replaced by the truth.

On the first :data:`N` (25) held-out generator samples of each generator in ``experiments/table_proposals.toml``
(never in training), scored as that table scores its ``proposal`` cells (K = 1 at 128 px, the prediction rescaled
about the input camera by ``align_scale``, held-out IoU over the protocol's held-out views), five variants of the
network's most probable proposal, each posed by one look (:func:`ipm.optim.pose.looks`: scale and translation
from the masks' areas and centroids; what the ``proposal`` bench method did before 10642c2) and by three looks in a
row (:func:`ipm.optim.pose.placed`, as the method does now at table_proposals' budget of 6):

- ``guess``: the network's proposal as it is;
- ``true discrete``: its discrete values replaced by the sample's;
- ``true yaw``: its yaw replaced by the sample's (0: the targets are the generator's meshes as it makes them);
- ``true continuous``: its continuous parameters replaced by the sample's;
- ``truth``: the sample's values at its yaw: what the one-look pose itself costs.

Each variant's sizes per count are held for its own counts (``Problem(reference=...)``, as the ``proposal`` method
and fits from proposals hold them): held for the default start's counts instead, the building's true values scored
0.801 (three looks), most of the gap to 1 being storeys squeezed to the height bound
(:meth:`ipm.optim.problem.Problem.carry`).

``python -m benchmarks.proposal_ablation`` (a few minutes, one thread) writes ``results/proposal_ablation.md``.
"""

from __future__ import annotations

import statistics
import sys
from dataclasses import replace
from pathlib import Path

import numpy as np
import torch

ROOT = Path(__file__).resolve().parents[1]
EXPERIMENT = ROOT / "experiments" / "table_proposals.toml"
N = 25
ROUNDS = (1, 3)  # looks in a row
VARIANTS = ("guess", "true discrete", "true yaw", "true continuous", "truth")


def _variant(name: str, guess, truth: dict, gen):
    """The proposal ``guess`` with what ``name`` says replaced by the sample's ``truth`` values."""
    discrete = {p.name for p in gen.spec.discrete}
    if name == "guess":
        return guess
    if name == "true discrete":
        return replace(guess, values={**guess.values, **{k: truth[k] for k in discrete}})
    if name == "true yaw":
        return replace(guess, yaw_deg=0.0)
    if name == "true continuous":
        return replace(guess, values={**guess.values, **{k: v for k, v in truth.items() if k not in discrete}})
    return replace(guess, values=dict(truth), yaw_deg=0.0)


def _score(exp_path: str, exp, name: str, proposer, gen, rounds: int) -> dict[str, float]:
    """Held-out IoU of every variant for target ``name`` (module docstring)."""
    from ipm.bench.harness import _heldout_cameras, _input_cameras, load_target, target_masks
    from ipm.bench.protocol import align_scale, render_masks, scale_about
    from ipm.bench.views import fit_views
    from ipm.metrics import mask_iou
    from ipm.optim.evaluator import Evaluator
    from ipm.optim.fit import FitSettings, MaskTarget, Problem
    from ipm.optim.pose import placed, proposed
    from ipm.types import TriMesh

    target = load_target(exp_path, name)
    cams = _input_cameras(exp, 1)
    masks, cams_f = fit_views(target_masks(exp_path, name, 1), cams, exp.size, torch.float32)
    guess = proposer.propose(masks[0], cams_f[0], k=1)[0]
    held = target_masks(exp_path, name, None)
    out = {}
    for v in VARIANTS:
        p = _variant(v, guess, target.truth, gen)
        prob = Problem(gen, MaskTarget(masks, cams_f), FitSettings(budget=2 * rounds, seed=0, init="presets"),
                       reference=p.values)
        ev = Evaluator(prob.objective, 2 * rounds)
        x, d = proposed(prob, [p], prob.x0())[0]
        x = placed(prob, ev, x, d, rounds)
        mesh = prob.mesh_world(x.to(torch.float64), d).detach()
        mesh = TriMesh(mesh.verts.double(), mesh.faces)
        mesh = scale_about(mesh, cams[0].eye, align_scale(mesh, target.mesh, cams[0].eye, seed=0).scale)
        pred = render_masks(mesh, _heldout_cameras(exp))
        out[v] = float(np.mean([mask_iou(a, b) for a, b in zip(pred, held)]))
    return out


def run(n: int = N, rounds: int = 1) -> list[str]:
    """The table's lines: per generator, the mean and median held-out IoU of each variant over ``n`` targets, each
    posed by ``rounds`` looks."""
    from ipm.bench.config import load_experiment
    from ipm.generators import get_generator
    from ipm.proposals import load_proposer

    torch.set_num_threads(1)
    exp = load_experiment(str(EXPERIMENT))
    lines = ["| generator | targets | " + " | ".join(VARIANTS) + " |", "|---" * (len(VARIANTS) + 2) + "|"]
    for g in sorted({t.generator for t in exp.targets}):
        gen = get_generator(g)
        proposer = load_proposer(gen, None)
        names = [t.name for t in exp.targets if t.generator == g][:n]
        scores = [_score(str(EXPERIMENT), exp, name, proposer, gen, rounds) for name in names]
        cells = [f"{statistics.mean(s[v] for s in scores):.3f} ({statistics.median(s[v] for s in scores):.3f})"
                 for v in VARIANTS]
        lines.append(f"| {g} | {len(names)} | " + " | ".join(cells) + " |")
    return lines


def main() -> int:
    from benchmarks.common import machine
    from ipm.files import write_text

    torch.set_num_threads(1)  # before machine(), which names the thread count
    lines = ["# The proposal alone, one part at a time replaced by the truth (issue #29)", "",
             f"Machine: {machine()}  ", "Command: `python -m benchmarks.proposal_ablation`", "",
             "\n\n".join(__doc__.split("\n\n")[1:3]).strip(), ""]
    for rounds in ROUNDS:
        lines += [f"Held-out IoU, mean (median), posed by {rounds} look{'s' if rounds > 1 else ''}:", "",
                  *run(N, rounds), ""]
    write_text(ROOT / "results" / "proposal_ablation.md", "\n".join(lines) + "\n")
    print("\n".join(lines))
    return 0


if __name__ == "__main__":
    sys.exit(main())
