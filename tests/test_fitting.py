"""The run folder (ipm.fitting): wall time summed over a resumed run's parts, and a resume whose replay does
not match its recorded run refused with InputError naming the folder and what differs."""

from __future__ import annotations

import json
import re

import pytest
from boxes import Boxes, boxes_target

import ipm
from ipm.errors import InputError
from ipm.io.masks import save_mask_set

SETTINGS = dict(discrete="none", budget=30, seed=2, lr=0.03)


@pytest.fixture(scope="module")
def masks(tmp_path_factory) -> str:
    t = boxes_target()
    folder = tmp_path_factory.mktemp("boxes") / "masks"
    save_mask_set(folder, t.masks.numpy(), t.cameras)
    return str(folder)


def _records(run) -> list[dict]:
    return [json.loads(line) for line in (run / "trajectory.jsonl").read_text().splitlines()]


def _write(run, records: list[dict]) -> None:
    (run / "trajectory.jsonl").write_text("".join(json.dumps(r) + "\n" for r in records))


def test_wall_time_counts_every_run_of_a_resumed_fit(masks, tmp_path):
    run = tmp_path / "run"
    first = ipm.fit(Boxes(), masks=masks, run_dir=run, **SETTINGS)
    records = _records(run)
    assert len(records) == 30 and first.wall_time_s >= records[-1]["t"] > 0
    # as if the first 12 evaluations had taken 1000 s before an interruption
    cut = [{**r, "t": r["t"] + 1000.0} for r in records[:12]]
    _write(run, cut)
    second = ipm.fit(Boxes(), run_dir=run, resume=True)
    result = json.loads((run / "result.json").read_text())
    assert result["wall_time_s"] == pytest.approx(second.wall_time_s, abs=1e-3)
    assert 1000.0 < second.wall_time_s < 1000.0 + 10 * first.wall_time_s + 60
    ts = [r["t"] for r in _records(run)]
    assert len(ts) == 30 and ts == sorted(ts) and ts[12] > 1000.0  # the new records go on counting
    assert second.loss == pytest.approx(first.loss, rel=1e-5)
    assert second.params == pytest.approx(first.params, rel=1e-5, abs=1e-7)


@pytest.mark.parametrize("local", ["adam", "mma"])
def test_a_resume_that_does_not_match_its_run_is_input_error(masks, tmp_path, local):
    run = tmp_path / "run"
    ipm.fit(Boxes(), masks=masks, run_dir=run, **{**SETTINGS, "local": local})
    records = _records(run)[:25]
    i = 20  # inside the search (after the pose grid), where mma runs in nlopt's callback
    records[i]["x"][0] = records[i]["x"][0] / 2 + 0.25
    _write(run, records)
    with pytest.raises(InputError, match=rf"--resume {run}: .*evaluation {i}: .*x\[0\]"):
        ipm.fit(Boxes(), run_dir=run, resume=True)


def test_resume_of_a_folder_that_is_not_a_run(tmp_path):
    with pytest.raises(InputError, match="expected a run folder"):
        ipm.fit(Boxes(), run_dir=tmp_path, resume=True)
    (tmp_path / "settings.json").write_text("{not json")
    with pytest.raises(InputError, match="expected JSON"):
        ipm.fit(Boxes(), run_dir=tmp_path, resume=True)


def test_bad_settings_are_input_errors(masks, tmp_path):
    for bad, msg in [(dict(seed=-1), "seed: expected a seed >= 0, got -1"),
                     (dict(prior_weight=float("nan")), "prior weight: expected a weight >= 0, got nan"),
                     (dict(polish=1.5), "polish: expected"), (dict(sigma=-1.0), "sigma: expected"),
                     (dict(budget=2.5), "budget: expected"), (dict(search={"memetic": {"tournament": 9}}), "tournament"),
                     (dict(search={"nlopt": {"algorithm": "GN_NOPE"}}), "nlopt algorithm: expected one of"),
                     (dict(free=["nope"]), "free parameters: expected continuous parameters"),
                     (dict(ranges={"count": [0, 9]}), "ranges: count: expected 1 <= lo <= hi <= 3")]:
        with pytest.raises(InputError, match=msg):
            ipm.fit(Boxes(), masks=masks, run_dir=tmp_path / "never", **bad)
        assert not (tmp_path / "never").exists()


@pytest.mark.parametrize("edit, words", [
    (lambda s: s.update(bogus=1), "unknown key(s) bogus"),
    (lambda s: s.update(search={"nope": {}}), "'nope': expected a search strategy"),
])
def test_a_resume_refuses_settings_it_does_not_know(masks, tmp_path, edit, words):
    """Issue #33: settings.json's keys are checked on resume, not dropped; the strategies' settings too."""
    run = tmp_path / "run"
    ipm.fit(Boxes(), masks=masks, discrete="none", budget=6, seed=0, run_dir=run)
    data = json.loads((run / "settings.json").read_text())
    edit(data["settings"])
    (run / "settings.json").write_text(json.dumps(data))
    with pytest.raises(InputError, match=re.escape(words)):
        ipm.fit(Boxes(), run_dir=run, resume=True)


def test_a_run_recorded_with_the_old_strategy_settings_resumes(masks, tmp_path):
    """Runs recorded before the strategies owned their settings kept "memetic" and "nlopt" at the top level."""
    run = tmp_path / "run"
    first = ipm.fit(Boxes(), masks=masks, discrete="none", budget=6, seed=0, run_dir=run)
    data = json.loads((run / "settings.json").read_text())
    data["settings"].pop("search")
    data["settings"].update(memetic={"population": 4}, nlopt={"algorithm": "GN_ESCH"})
    (run / "settings.json").write_text(json.dumps(data))
    again = ipm.fit(Boxes(), run_dir=run, resume=True)
    assert again.params == first.params


def test_an_sdf_run_recorded_before_the_mesh_silhouettes_resumes_with_the_tracer(masks, tmp_path):
    """Runs of SDF generators recorded before ``sdf_silhouette`` existed were sphere-traced; their settings lack the
    key, and they resume (replaying their trajectory) with the tracer, not the new default."""
    run = tmp_path / "run"
    first = ipm.fit("csg", masks=masks, discrete="none", budget=6, seed=0, run_dir=run, sdf_silhouette="trace")
    data = json.loads((run / "settings.json").read_text())
    assert data["settings"].pop("sdf_silhouette") == "trace"
    (run / "settings.json").write_text(json.dumps(data))
    again = ipm.fit("csg", run_dir=run, resume=True)
    assert again.params == first.params
