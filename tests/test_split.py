"""Tune / validation splits of an experiment (issue #34): the public table's split is the seeded draw of
benchmarks/draw_split.py, ``ipm bench --split`` runs one split, and a target's split is not part of what its
rows depend on (moving a target between splits keeps its rows)."""

from __future__ import annotations

from pathlib import Path

import pytest

from benchmarks.draw_split import EXPERIMENT, TUNED_BEFORE, draw
from ipm.bench.config import load_experiment
from ipm.bench.harness import cell_identities
from ipm.errors import InputError

TWO = ('name = "e"\nviews = [1]\n'
       '[[targets]]\nname = "a"\ngenerator = "dishes"\npreset = "mug"\nsplit = "tune"\n'
       '[[targets]]\nname = "b"\ngenerator = "dishes"\npreset = "bowl"\nsplit = "validation"\n'
       '[[methods]]\nname = "vh"\nmethod = "visual-hull"\n'
       '[[methods]]\nname = "vh_a"\nmethod = "visual-hull"\ntargets = ["a"]\n')


def test_the_public_table_split_is_the_seeded_draw():
    exp = load_experiment(EXPERIMENT)
    drawn = draw(exp.targets)
    assert {t.name: t.split for t in exp.targets} == drawn
    validation = [t for t in exp.targets if t.split == "validation"]
    # never tuned on: no validation target is a file an earlier table used
    assert validation and not any("/".join(Path(t.mesh).parts[-2:]) in TUNED_BEFORE for t in validation)
    for cls in {t.cls for t in exp.targets}:  # about half of each class, where the class has unused files
        n = sum(t.cls == cls for t in exp.targets)
        v = sum(t.cls == cls for t in validation)
        assert v <= (n + 1) // 2


def test_the_draw_does_not_depend_on_the_order_of_the_file():
    exp = load_experiment(EXPERIMENT)
    assert draw(reversed(exp.targets)) == draw(exp.targets)


def test_split_keeps_its_targets_and_methods_limited_to_others_stay_valid(tmp_path):
    path = tmp_path / "e.toml"
    path.write_text(TWO)
    assert sorted(c.key for c in load_experiment(path).cells()) == ["a|vh_a|1|0", "a|vh|1|0", "b|vh|1|0"]
    assert sorted(c.key for c in load_experiment(path, "validation").cells()) == ["b|vh|1|0"]
    assert sorted(c.key for c in load_experiment(path, "tune").cells()) == ["a|vh_a|1|0", "a|vh|1|0"]
    with pytest.raises(InputError, match=r"--split test: expected a split of .* \(tune, validation\), got one "
                                         "with no target"):
        load_experiment(path, "test")


def test_split_is_not_part_of_a_cells_identity(tmp_path):
    path = tmp_path / "e.toml"
    path.write_text(TWO)
    before = cell_identities(str(path), load_experiment(path))
    path.write_text(TWO.replace('split = "validation"', 'split = "tune"'))
    assert cell_identities(str(path), load_experiment(path)) == before
    path.write_text(TWO.replace('preset = "bowl"', 'preset = "plate"'))
    after = cell_identities(str(path), load_experiment(path))
    assert after["b|vh|1|0"] != before["b|vh|1|0"] and after["a|vh|1|0"] == before["a|vh|1|0"]


def test_bench_split_option_refuses_an_unknown_split(tmp_path, capsys):
    from ipm.cli import main

    path = tmp_path / "e.toml"
    path.write_text(TWO.replace('split = "tune"\n', "").replace('split = "validation"\n', ""))
    with pytest.raises(SystemExit) as e:
        main(["bench", str(path), "-o", str(tmp_path / "out"), "--split", "validation", "--dry-run"])
    assert e.value.code == 2
    err = capsys.readouterr().err.strip()
    assert err.count("\n") == 0 and "it has none: give targets a split key" in err
    assert not (tmp_path / "out").exists()


def test_the_validation_coverage_table_holds_the_validation_splits_vessels_and_buildings_as_table1_does():
    """experiments/coverage_validation.toml copies its targets and its fits' settings from table1.toml (the
    validation split, furniture left out) and table_coverage.toml (the 8-view fit): a target or a setting changed in
    one file and not the other would make the two tables measure different things."""
    table1, coverage = load_experiment(EXPERIMENT), load_experiment("experiments/table_coverage.toml")
    cv = load_experiment("experiments/coverage_validation.toml")
    wanted = [t for t in table1.targets if t.split == "validation" and t.cls not in ("chair", "table")]
    assert list(cv.targets) == wanted
    for t in cv.targets:
        assert cv.method("ipm").settings_for(t) == table1.method("ipm").settings_for(t)
        assert cv.method("ipm-bound").settings_for(t) == coverage.method("ipm-bound").settings_for(t)
    assert (cv.budget, cv.size, cv.heldout_size) == (table1.budget, table1.size, table1.heldout_size)
