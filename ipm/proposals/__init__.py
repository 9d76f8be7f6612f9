"""Learned proposals: a first guess of a generator's parameters, discrete values and yaw from one mask, in
milliseconds, from a small network trained on the CPU on the generator's own samples (issue #29).

``ipm train-proposals GEN -o WEIGHTS`` trains one (:mod:`ipm.proposals.train`); weights for ``dishes`` and
``building`` ship in ``ipm/proposals/weights/`` (plain arrays, rebuilt by ``make proposals``) and ``ipm list
proposals`` shows them; a fit with ``--init learned`` starts from the network's top proposals in place of the
start and the presets, with ``--init both`` beside the presets (:func:`ipm.optim.fit.run_fit`).

Modules: what the network sees (``encode``), the network and its weights files (``net``), training data
(``data``), training (``train``), proposals from a trained network (``propose``).
"""

from __future__ import annotations

from pathlib import Path

from ipm.proposals.propose import Proposal, Proposer

WEIGHTS_DIR = Path(__file__).resolve().parent / "weights"


def shipped() -> dict[str, Path]:
    """The shipped weights files by generator name."""
    return {p.stem: p for p in sorted(WEIGHTS_DIR.glob("*.npz"))}


def load_proposer(gen, weights: str | Path | None = None) -> Proposer | None:
    """The proposer of ``gen`` from ``weights`` (a file), or from the shipped weights of its name; None when
    there are none. ``InputError`` for a file that is not weights or was trained for other parameters."""
    from ipm.proposals.net import load_weights

    path = Path(weights) if weights is not None else shipped().get(gen.name)
    if path is None:
        return None
    net, _ = load_weights(path, gen)
    return Proposer(net, gen, str(path))


__all__ = ["WEIGHTS_DIR", "Proposal", "Proposer", "load_proposer", "shipped"]
