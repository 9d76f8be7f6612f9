"""The five reference fits of issue #33 (benchmarks/reference_fits.py): reorganizing the fit's code must not change
what the fits do. On the machine the fingerprints were recorded on (tests/data/reference_fits.json names it)
every record must be the same bit for bit; on another machine the last bits differ, and the final numbers must
agree within the tolerance of results/perturbation.md (the photo fit, which has two modes there, excepted)."""

from __future__ import annotations

import json
from pathlib import Path

import pytest

from benchmarks.reference_fits import STORED, machine, run_all
from tests.conftest import require_file

pytestmark = pytest.mark.slow
TOLERANCE = 0.005


def test_the_reference_fits_are_unchanged(tmp_path):
    from ipm import data as D

    require_file(D.root() / D.MUG)
    stored = json.loads(Path(STORED).read_text())
    got = run_all(tmp_path)
    assert set(got) == set(stored["fits"])
    if machine() == stored["machine"]:
        for name, want in stored["fits"].items():
            assert got[name]["fingerprint"] == want["fingerprint"], (name, got[name], want)
        return
    for name, want in stored["fits"].items():
        if name == "photo":  # two modes on other machines (issue #28's note): only what both share
            assert got[name]["final"]["photo_iou"] >= 0.90 and got[name]["final"]["has_handle"] == 1
            continue
        for key, value in want["final"].items():
            if isinstance(value, int):
                assert got[name]["final"][key] == value, (name, key)
            else:
                assert abs(got[name]["final"][key] - value) <= TOLERANCE, (name, key, got[name], want)
