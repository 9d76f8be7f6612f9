"""Writes ``experiments/table_proposals.toml``: held-out generator samples for the learned proposals (issue #29).

``python -m benchmarks.proposal_targets [N]`` draws N samples (default 200) of each generator with shipped
proposal weights from :data:`ipm.proposals.train.HELDOUT_SEED`'s stream, which no training seed draws, by the
training data's own sampler (:func:`ipm.proposals.data.sample_values`: presets mixed, values moved), and writes
them as generator targets with their values, one class per generator. ``make table-proposals`` runs the file.
"""

from __future__ import annotations

import sys
from pathlib import Path

import numpy as np

from ipm.files import write_text

ROOT = Path(__file__).resolve().parents[1]
OUT = ROOT / "experiments" / "table_proposals.toml"
HEAD = '''# Learned proposals on held-out generator samples (issue #29). Written by
# `python -m benchmarks.proposal_targets {n}`: {n} samples of each generator drawn by the proposal networks'
# own training sampler (presets mixed, values moved; ipm.proposals.data.sample_values) from the held-out
# seed's stream, which no training run draws.
# `proposal` is the network's most probable guess from the one input view, posed by three looks in a row
# (areas and centroids: the budget of 6 is two evaluations a look) and not refined. Scored as every table
# (protocol v2, K = 1 scaled about the eye), at 128 px in and out with 4000 surface samples to keep {total}
# cells affordable. Run with `make table-proposals` (results/table_proposals/).
name = "table_proposals"
views = [1]
seeds = [0]
budget = 6
size = 128
heldout_size = 128
samples = 4000
iou_resolution = 48
notes = """
Held-out generator samples the proposal networks never saw; `proposal` is the network's best guess with no
refinement (three looks, six evaluations, to set its scale and place). Discrete accuracy: share of the discrete
parameters recovered exactly; parameter error: mean |error| of the continuous parameters in normalized [0, 1]
units.
"""
'''


def _value(v) -> str:
    return repr(int(v)) if isinstance(v, int) and not isinstance(v, bool) else repr(round(float(v), 6))


def main(argv: list[str]) -> int:
    from ipm.generators import get_generator
    from ipm.proposals import shipped
    from ipm.proposals.data import sample_values
    from ipm.proposals.train import HELDOUT_SEED

    n = int(argv[0]) if argv else 200
    names = sorted(shipped())
    parts = [HEAD.format(n=n, total=n * len(names))]
    for g_name in names:
        gen = get_generator(g_name)
        rng = np.random.default_rng(HELDOUT_SEED)
        parts.append(f"# -- {g_name} --\n")
        for i in range(n):
            values = sample_values(gen, rng)
            params = ", ".join(f"{k} = {_value(v)}" for k, v in values.items())
            parts.append(f'[[targets]]\nname = "{g_name}_{i:03d}"\nclass = "{g_name}"\ngenerator = "{g_name}"\n'
                         f"params = {{ {params} }}\n\n")
    parts.append('[[methods]]\nname = "proposal"\nmethod = "proposal"\nviews = [1]\nseeds = [0]\n\n'
                 "[methods.by_class]\n" + "".join(f'{g} = {{ generator = "{g}" }}\n' for g in names))
    write_text(OUT, "".join(parts))
    print(OUT)
    return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
