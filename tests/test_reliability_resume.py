"""Resume files and run folders under bad input (issue #32): ``ipm fit --resume``, ``ipm fit --structure
search --resume`` and ``ipm bench --resume``.

1. A damaged resume file (binary, not an object, a field of the wrong type or missing) is bad input: exit 2,
   one line ``ipm: error: ...`` naming the file and the field, nothing changed.
2. A run resumes as documented: a fit whose generator was a tree file, with ``--library``, from another
   working folder.
3. A first run that cannot write its run folder (a full disk at the Nth write) leaves no run folder; a
   resume that cannot write keeps its folder resumable.
4. Edited records are refused: a trajectory whose losses (or gradients) were edited, a structure search
   checkpoint whose scores were, a bench folder of another experiment.

Inputs are built in ``tmp/in``, outputs go to ``tmp/out``; after a refusal ``tmp/out`` does not exist and
every file in ``tmp/in`` has its content of before. Tiny inputs (one 32-pixel view), budgets of a few dozen
evaluations.
"""

from __future__ import annotations

import builtins
import errno
import hashlib
import io
import json
import shutil
from pathlib import Path

import pytest
from conftest import run_cli as run

from ipm.cli import main

FIT_BUDGET = 40       # pose grid (16), two starts refined, the polish: phases init, multistart:0/1, polish:0
STRUCTURE_BUDGET = 650  # the default polish (600) and 50 evaluations of search


def _ok(args) -> None:
    """Run ``ipm`` in this process and require exit 0 (its output goes to pytest's capture)."""
    with pytest.raises(SystemExit) as e:
        main([str(a) for a in args])
    assert e.value.code == 0


def _tree_json() -> dict:
    return {"tree": {"node": "union", "children": [
        {"node": "translate", "params": {"y": -0.3}, "children": [
            {"node": "cylinder", "params": {"radius": 0.3, "height": 0.8}}]},
        {"node": "sphere", "params": {"radius": 0.4}}]}}


@pytest.fixture(scope="module")
def shared(tmp_path_factory) -> dict[str, Path]:
    """Made once: a mask set, a finished fit run, a finished structure search and a bench folder."""
    root = tmp_path_factory.mktemp("resume")
    masks = root / "masks"
    _ok(["render", "dishes", "--preset", "mug", "--views", "1", "--size", "32", "--no-previews", "-q", "-o", masks])
    fit = root / "fit"
    _ok(["fit", "dishes", "--masks", masks, "--budget", FIT_BUDGET, "--discrete", "none", "-q", "-o", fit])
    tree = root / "tree.json"
    tree.write_text(json.dumps(_tree_json()))
    mesh = root / "tree.obj"
    _ok(["generate", tree, "--resolution", "32", "-q", "-o", mesh])
    structure = root / "structure"
    _ok(["fit", "--structure", "search", "--target-mesh", mesh, "--budget", STRUCTURE_BUDGET, "-q", "-o", structure])
    exp = _experiment(root)
    bench = root / "bench"
    _ok(["bench", exp, "-q", "-o", bench])
    return {"root": root, "masks": masks, "fit": fit, "structure": structure, "bench": bench, "experiment": exp}


BENCH = """name = "e"
budget = 2
size = 64
heldout_size = 64
samples = 200
views = [1]
seeds = SEEDS
[[targets]]
name = "s"
generator = "dishes"
preset = "mug"
[[methods]]
name = "vh"
method = "visual-hull"
resolution = RESOLUTION
"""


def _experiment(folder: Path, name: str = "e", seeds=(0,), resolution: int = 16) -> Path:
    (folder / "experiments").mkdir(exist_ok=True)
    path = folder / "experiments" / f"{name}.toml"
    path.write_text(BENCH.replace('"e"', f'"{name}"').replace("SEEDS", str(list(seeds)))
                    .replace("RESOLUTION", str(resolution)))
    return path


def _records(path: Path) -> list[dict]:
    return [json.loads(line) for line in path.read_text().splitlines()]


def _write_records(path: Path, records: list[dict]) -> None:
    path.write_text("".join(json.dumps(r) + "\n" for r in records))


def _edit_json(path: Path, change) -> None:
    """``change`` the JSON of ``path`` in place (its return value is ignored)."""
    data = json.loads(path.read_text())
    change(data)
    path.write_text(json.dumps(data))


def _edit_records(path: Path, change) -> None:
    """``change`` the records of ``path`` in place, or return a list of records instead."""
    records = _records(path)
    out = change(records)
    _write_records(path, out if isinstance(out, list) else records)


def _contents(folder: Path) -> dict[str, str]:
    return {str(p.relative_to(folder)): hashlib.sha256(p.read_bytes()).hexdigest() if p.is_file() else "dir"
            for p in sorted(folder.rglob("*"))} if folder.exists() else {}


# -- 1. damaged resume files, and 4. edited ones: exit 2, one line naming the file and the field -------------

def _fit(i: Path, shared, damage=None, gen: bool = False) -> list:
    run_dir = i / "run"
    shutil.copytree(shared["fit"], run_dir)
    if damage is not None:
        damage(run_dir)
    return ["fit", *(["dishes"] if gen else []), "--resume", run_dir]


def _settings(change):
    return lambda r: _edit_json(r / "settings.json", change)


def _trajectory(change):
    return lambda r: _edit_records(r / "trajectory.jsonl", change)


def _binary(name: str):
    return lambda r: (r / name).write_bytes(b"\x89PNG\r\n\x1a\n\x00\xff\xfe")


def _cut(n: int, change=None):
    """The first ``n`` records (an interrupted run), then ``change`` applied to them."""
    def damage(records):
        records[:] = records[:n]
        if change is not None:
            change(records)
    return _trajectory(damage)


def _set(i: int, key: str, value):
    def change(records):
        records[i][key] = value
    return change


def _structure(i: Path, shared, damage) -> list:
    run_dir = i / "run"
    shutil.copytree(shared["structure"], run_dir)
    damage(run_dir)
    return ["fit", "--resume", run_dir]


def _checkpoint(change):
    return lambda r: _edit_json(r / "checkpoint.json", change)


def _bench(i: Path, shared, damage, experiment=None) -> list:
    out = i / "bench"
    shutil.copytree(shared["bench"], out)
    damage(out)
    return ["bench", experiment(i) if experiment else shared["experiment"], "-o", out, "--resume"]


def _rows(change):
    return lambda o: _edit_records(o / "rows.jsonl", change)


# case -> (arguments given the input folder and the shared runs, words the message must contain)
CASES = {
    # fit: settings.json
    "fit settings binary": (lambda i, s: _fit(i, s, _binary("settings.json")), ["settings.json", "binary"]),
    "fit settings binary, GEN given": (lambda i, s: _fit(i, s, _binary("settings.json"), gen=True),
                                       ["settings.json", "binary"]),
    "fit settings a list": (lambda i, s: _fit(i, s, _json_file("settings.json", [1, 2])),
                            ["settings.json", "object"]),
    "fit settings a string, GEN given": (lambda i, s: _fit(i, s, _json_file("settings.json", "run"), gen=True),
                                         ["settings.json", "object"]),
    "fit settings not JSON": (lambda i, s: _fit(i, s, lambda r: (r / "settings.json").write_text("{oops")),
                              ["settings.json", "JSON"]),
    "fit settings nested 100000 deep": (lambda i, s: _fit(i, s, lambda r: (r / "settings.json").write_text(
        "[" * 100_000 + "]" * 100_000)), ["settings.json", "deep"]),
    "fit settings without a generator": (lambda i, s: _fit(i, s, _settings(lambda d: d.pop("generator"))),
                                         ["settings.json", "generator", "nothing"]),
    "fit settings' settings a string": (lambda i, s: _fit(i, s, _settings(lambda d: d.update(settings="abc"))),
                                        ["settings.json", "settings", "'abc'"]),
    "fit settings' budget a string": (lambda i, s: _fit(i, s, _settings(lambda d: d["settings"].update(budget="x")),
                                                        gen=True), ["settings.json", "budget", "'x'"]),
    "fit settings' memetic a number": (lambda i, s: _fit(i, s, _settings(lambda d: d["settings"].update(memetic=3))),
                                       ["settings.json", "memetic"]),
    "fit settings' target masks a number": (
        lambda i, s: _fit(i, s, _settings(lambda d: d["target"].update(masks=3))), ["settings.json", "masks", "3"]),
    "fit settings' target box not 4 numbers": (
        lambda i, s: _fit(i, s, _settings(lambda d: d["target"].update(box="a"))), ["settings.json", "box"]),
    "fit settings' target a list": (lambda i, s: _fit(i, s, _settings(lambda d: d.update(target=[1]))),
                                    ["settings.json", "target", "object"]),
    "fit settings' source a number": (lambda i, s: _fit(i, s, _settings(lambda d: d.update(source=5))),
                                      ["settings.json", "source", "string"]),
    "fit settings' library a string": (lambda i, s: _fit(i, s, _settings(lambda d: d.update(library="lib"))),
                                       ["settings.json", "library", "list"]),
    # fit: trajectory.jsonl
    "fit trajectory binary": (lambda i, s: _fit(i, s, _binary("trajectory.jsonl")), ["trajectory.jsonl", "binary"]),
    "fit trajectory binary, GEN given": (lambda i, s: _fit(i, s, _binary("trajectory.jsonl"), gen=True),
                                         ["trajectory.jsonl", "binary"]),
    "fit trajectory line a list": (lambda i, s: _fit(i, s, _trajectory(lambda r: r.insert(3, [1, 2]))),
                                   ["trajectory.jsonl", "line 4", "object"]),
    "fit trajectory line a number, GEN given": (lambda i, s: _fit(i, s, _trajectory(lambda r: r.insert(0, 7)),
                                                                  gen=True), ["trajectory.jsonl", "line 1"]),
    "fit trajectory line not JSON": (
        lambda i, s: _fit(i, s, lambda r: (r / "trajectory.jsonl").write_text(
            "{oops\n" + (r / "trajectory.jsonl").read_text())), ["trajectory.jsonl", "line 1", "JSON"]),
    "fit trajectory line nested 100000 deep": (lambda i, s: _fit(i, s, lambda r: (r / "trajectory.jsonl").write_text(
        "[" * 100_000 + "]" * 100_000 + "\n")), ["trajectory.jsonl", "line 1", "deep"]),
    "fit trajectory record without a loss": (lambda i, s: _fit(i, s, _trajectory(lambda r: r[2].pop("loss"))),
                                             ["trajectory.jsonl", "line 3", "loss", "nothing"]),
    "fit trajectory loss a string": (lambda i, s: _fit(i, s, _trajectory(_set(5, "loss", "low"))),
                                     ["trajectory.jsonl", "line 6", "loss", "'low'"]),
    "fit trajectory loss not finite": (lambda i, s: _fit(i, s, _trajectory(_set(5, "loss", float("nan")))),
                                       ["trajectory.jsonl", "line 6", "loss", "finite"]),
    "fit trajectory x a string": (lambda i, s: _fit(i, s, _trajectory(_set(1, "x", "abc"))),
                                  ["trajectory.jsonl", "line 2", "x", "list"]),
    "fit trajectory x out of [0, 1]": (lambda i, s: _fit(i, s, _trajectory(lambda r: r[1]["x"].__setitem__(0, 7.0))),
                                       ["trajectory.jsonl", "line 2", "x", "[0, 1]"]),
    "fit trajectory discrete value a string": (
        lambda i, s: _fit(i, s, _trajectory(lambda r: r[1]["discrete"].update(handles="two"))),
        ["trajectory.jsonl", "line 2", "discrete"]),
    "fit trajectory grad of another length": (
        lambda i, s: _fit(i, s, _trajectory(lambda r: r[20]["grad"].pop())), ["trajectory.jsonl", "line 21", "grad"]),
    "fit trajectory records out of order": (lambda i, s: _fit(i, s, _trajectory(_set(4, "i", 9))),
                                            ["trajectory.jsonl", "line 5", "i"]),
    # fit: edited records (4.)
    "fit edited loss of the last record replayed": (
        lambda i, s: _fit(i, s, _cut(30, lambda r: r[29].update(loss=r[29]["loss"] * 0.5))),
        ["trajectory.jsonl", "evaluation 29", "loss"]),
    "fit edited loss, the lowest of its phase": (
        lambda i, s: _fit(i, s, _cut(30, _set(20, "loss", 0.001))), ["trajectory.jsonl", "evaluation 20", "loss"]),
    "fit edited loss of a finished run, GEN given": (
        lambda i, s: _fit(i, s, _trajectory(lambda r: r[-1].update(loss=r[-1]["loss"] + 0.01)), gen=True),
        ["trajectory.jsonl", f"evaluation {FIT_BUDGET - 1}", "loss"]),
    "fit edited gradient of the last record replayed": (
        lambda i, s: _fit(i, s, _cut(30, lambda r: r[29]["grad"].__setitem__(0, r[29]["grad"][0] + 1.0))),
        ["trajectory.jsonl", "evaluation 29", "grad[0]"]),
    "fit target masks changed since": (
        lambda i, s: _fit(i, s, lambda r: _settings(lambda d: d["target"].update(masks=str(_other_masks(i))))(r)),
        ["trajectory.jsonl", "evaluation"]),
    # structure search: settings.json and checkpoint.json
    "structure settings binary": (lambda i, s: _structure(i, s, _binary("settings.json")),
                                  ["settings.json", "binary"]),
    "structure settings' budget a string": (
        lambda i, s: _structure(i, s, _settings(lambda d: d["structure"].update(budget="x"))),
        ["settings.json", "budget", "'x'"]),
    "structure settings' target mesh a number": (
        lambda i, s: _structure(i, s, _settings(lambda d: d["target"].update(target_mesh=3))),
        ["settings.json", "target.target_mesh", "string"]),
    "structure checkpoint binary": (lambda i, s: _structure(i, s, _binary("checkpoint.json")),
                                    ["checkpoint.json", "binary"]),
    "structure checkpoint a list": (lambda i, s: _structure(i, s, _json_file("checkpoint.json", [1])),
                                    ["checkpoint.json", "object"]),
    "structure checkpoint records a string": (lambda i, s: _structure(i, s, _checkpoint(lambda d: d.update(
        records="abc"))), ["checkpoint.json", "records", "'abc'"]),
    "structure checkpoint records beyond the file": (lambda i, s: _structure(i, s, _checkpoint(lambda d: d.update(
        records=10 ** 6))), ["checkpoint.json", "records", "structures.jsonl"]),
    "structure checkpoint round a float": (lambda i, s: _structure(i, s, _checkpoint(lambda d: d.update(round=1.5))),
                                           ["checkpoint.json", "round", "1.5"]),
    "structure checkpoint without elapsed": (lambda i, s: _structure(i, s, _checkpoint(lambda d: d.pop("elapsed"))),
                                             ["checkpoint.json", "elapsed", "nothing"]),
    "structure checkpoint nested 100000 deep": (lambda i, s: _structure(i, s, lambda r: (
        r / "checkpoint.json").write_text("[" * 100_000 + "]" * 100_000)), ["checkpoint.json", "deep"]),
    "structure checkpoint beam empty": (lambda i, s: _structure(i, s, _checkpoint(lambda d: d.update(beam=[]))),
                                        ["checkpoint.json", "beam", "empty"]),
    "structure checkpoint beam a string": (lambda i, s: _structure(i, s, _checkpoint(lambda d: d.update(beam="x"))),
                                           ["checkpoint.json", "beam", "'x'"]),
    "structure checkpoint tree a number": (
        lambda i, s: _structure(i, s, _checkpoint(lambda d: d["beam"][0].update(tree=5))),
        ["checkpoint.json", "beam[0].tree", "object"]),
    "structure checkpoint tree of an unknown node": (
        lambda i, s: _structure(i, s, _checkpoint(lambda d: d["best"].update(tree={"node": "blob"}))),
        ["checkpoint.json", "best.tree", "blob"]),
    "structure checkpoint stopped unknown": (
        lambda i, s: _structure(i, s, _checkpoint(lambda d: d.update(stopped="bored"))),
        ["checkpoint.json", "stopped", "'bored'"]),
    "structure checkpoint nodes miscounted": (
        lambda i, s: _structure(i, s, _checkpoint(lambda d: d["beam"][0].update(nodes=7))),
        ["checkpoint.json", "beam[0].nodes", "7"]),
    "structure checkpoint edited score": (
        lambda i, s: _structure(i, s, _checkpoint(lambda d: d["best"].update(score=d["best"]["score"] / 2))),
        ["checkpoint.json", "best.score"]),
    "structure checkpoint edited IoU": (
        lambda i, s: _structure(i, s, _checkpoint(lambda d: d["beam"][0].update(iou=1.0))),
        ["checkpoint.json", "beam[0].iou"]),
    "structure records binary": (lambda i, s: _structure(i, s, _binary("structures.jsonl")),
                                 ["structures.jsonl", "binary"]),
    # bench: rows.jsonl and experiment.json
    "bench rows binary": (lambda i, s: _bench(i, s, _binary("rows.jsonl")), ["rows.jsonl", "binary"]),
    "bench row without its key": (lambda i, s: _bench(i, s, _rows(lambda r: r[0].pop("key"))),
                                  ["rows.jsonl", "line 1", "key", "nothing"]),
    "bench row a list": (lambda i, s: _bench(i, s, _rows(lambda r: r.insert(0, [1]))),
                         ["rows.jsonl", "line 1", "object"]),
    "bench row not JSON": (lambda i, s: _bench(i, s, lambda o: (o / "rows.jsonl").write_text(
        "{oops\n" + (o / "rows.jsonl").read_text())), ["rows.jsonl", "line 1", "JSON"]),
    "bench row views a string": (lambda i, s: _bench(i, s, _rows(_set(0, "views", "one"))),
                                 ["rows.jsonl", "line 1", "views", "'one'"]),
    "bench row IoU a string": (lambda i, s: _bench(i, s, _rows(_set(0, "heldout_iou", "good"))),
                               ["rows.jsonl", "line 1", "heldout_iou", "'good'"]),
    "bench row status unknown": (lambda i, s: _bench(i, s, _rows(_set(0, "status", "meh"))),
                                 ["rows.jsonl", "line 1", "status"]),
    "bench row key of another cell": (lambda i, s: _bench(i, s, _rows(_set(0, "key", "s|vh|1|7"))),
                                      ["rows.jsonl", "line 1", "key", "s|vh|1|7"]),
    "bench row twice": (lambda i, s: _bench(i, s, _rows(lambda r: r.append(dict(r[0])))),
                        ["rows.jsonl", "line 2", "s|vh|1|0"]),
    "bench experiment file damaged": (lambda i, s: _bench(i, s, _json_file("experiment.json", {"name": 3})),
                                      ["experiment.json", "name", "3"]),
    "bench experiment file binary": (lambda i, s: _bench(i, s, _binary("experiment.json")),
                                     ["experiment.json", "binary"]),
    # bench: another experiment (4.)
    "bench another experiment's folder": (
        lambda i, s: _bench(i, s, lambda o: None, lambda i: _experiment(i, "f", resolution=20)),
        ["experiment 'e'", "experiment 'f'", "s|vh|1|0"]),
    "bench another experiment's folder, kept before experiment.json": (
        lambda i, s: _bench(i, s, lambda o: ((o / "experiment.json").unlink(), _rows(_set(0, "target", "t"))(o),
                                             _rows(_set(0, "key", "t|vh|1|0"))(o)),
                            lambda i: _experiment(i, "f")), ["experiment 'f'", "t|vh|1|0"]),
}


def _json_file(name: str, data) -> callable:
    return lambda o: (o / name).write_text(json.dumps(data))


def _other_masks(i: Path) -> Path:
    """Masks of another shape (a teacup instead of the mug) in ``i/other_masks``."""
    out = i / "other_masks"
    _ok(["render", "dishes", "--preset", "teacup", "--views", "1", "--size", "32", "--no-previews", "-q", "-o", out])
    return out


@pytest.mark.parametrize("case", sorted(CASES))
def test_bad_resume_files_exit_2_with_one_line_naming_the_file(case, shared, tmp_path, capsys):
    make, words = CASES[case]
    i, o = tmp_path / "in", tmp_path / "out"
    i.mkdir()
    args = make(i, shared)
    before = _contents(i)
    capsys.readouterr()
    code, stdout, err = run(args, capsys)
    lines = err.strip().splitlines()
    assert code == 2, f"{case}: exit {code}, stderr: {err}"
    assert len(lines) == 1 and lines[0].startswith("ipm: error: "), f"{case}: stderr: {err!r}"
    for word in words:
        assert word.lower() in lines[0].lower(), f"{case}: {lines[0]!r} does not name {word!r}"
    assert stdout == ""
    assert not o.exists()
    assert _contents(i) == before, f"{case}: changed {sorted(set(_contents(i).items()) ^ set(before.items()))}"


def test_the_table_covers_every_kind_of_resume_file():
    assert len(CASES) >= 50
    for kind in ("fit settings", "fit trajectory", "fit edited", "structure settings", "structure checkpoint",
                 "bench rows", "bench row", "bench experiment", "bench another"):
        assert any(c.startswith(kind) for c in CASES), kind


# -- unchanged resumes still pass, and the checks cost little ----------------------------------------------------

def _result(run_dir: Path) -> dict:
    out = json.loads((run_dir / "result.json").read_text())
    return {k: out[k] for k in ("loss", "params", "discrete", "evaluations")}


def test_an_interrupted_fit_resumes_to_the_uninterrupted_answer_with_few_re_evaluations(shared, tmp_path, capsys,
                                                                                       monkeypatch):
    """Records cut at 30 of 40 (and a torn 31st line): the resume reproduces the uninterrupted run bit for bit
    and evaluates again only the records :func:`checked_records` names (one per phase and the last)."""
    from ipm.optim import evaluator as E

    run_dir = tmp_path / "run"
    shutil.copytree(shared["fit"], run_dir)
    for name in ("result.json", "params.json", "mesh.glb", "mesh.obj", "loss.png", "overlay_000.png"):
        (run_dir / name).unlink()
    lines = (run_dir / "trajectory.jsonl").read_text().splitlines()
    (run_dir / "trajectory.jsonl").write_text("\n".join(lines[:30]) + "\n" + lines[30][:40])
    checks = []
    real = E.Evaluator._check
    monkeypatch.setattr(E.Evaluator, "_check", lambda self, rec, *a: (checks.append(rec["i"]), real(self, rec, *a)))
    code, _, err = run(["fit", "--resume", run_dir], capsys)
    assert code == 0, err
    assert _result(run_dir) == _result(shared["fit"])
    assert checks == sorted(E.checked_records(_records(shared["fit"] / "trajectory.jsonl")[:30]))
    assert len(checks) <= 4  # phases init, multistart:0, multistart:1, and the last record


def test_a_replay_re_evaluates_few_records_and_names_the_first_that_differs():
    """The evaluator alone: six records in two phases; replayed against the same objective only the checked
    records are evaluated again; against an objective that moved, the first checked one is named."""
    import torch

    from ipm.optim.evaluator import Evaluator, ReplayMismatch, checked_records

    def objective(shift):
        calls = []

        def f(x, d, grad):
            calls.append(1)
            return (x ** 2).sum() + shift, 2 * x, {}
        return f, calls

    points = [torch.full((2,), v) for v in (0.9, 0.5, 0.7, 0.3, 0.2, 0.4)]
    records = []
    ev = Evaluator(objective(0.0)[0], 6, sink=records.append)
    for k, x in enumerate(points):
        ev.phase = "a" if k < 3 else "b"
        ev(x, {})
    assert checked_records(records) == {1, 4, 5}
    for shift, expect in ((0.0, None), (1e-9, None), (0.01, 1)):
        f, calls = objective(shift)
        ev = Evaluator(f, 6, replay=records)
        if expect is None:
            for x in points:
                ev(x, {})
            assert len(calls) == 3 and ev.best.index == 4
        else:
            with pytest.raises(ReplayMismatch, match=f"evaluation {expect}: .*loss"):
                for x in points:
                    ev(x, {})


def test_checked_records_are_the_last_and_the_lowest_of_each_phase():
    from ipm.optim.evaluator import checked_records

    recs = [{"phase": "a", "loss": 3.0}, {"phase": "a", "loss": 1.0}, {"phase": "b", "loss": 2.0},
            {"phase": "b", "loss": 2.0}, {"phase": "a", "loss": 5.0}]
    assert checked_records(recs) == {1, 2, 4}
    assert checked_records([]) == set()


def test_a_finished_bench_grows_by_a_seed_and_accepts_a_folder_from_before_experiment_json(shared, tmp_path, capsys):
    """Adding cells (a seed) resumes into the same folder; a folder without experiment.json whose rows are all
    cells of the experiment is accepted (and gets one); a torn last row is dropped."""
    out = tmp_path / "bench"
    shutil.copytree(shared["bench"], out)
    (tmp_path / "grown").mkdir()
    grown = _experiment(tmp_path / "grown", "e", seeds=(0, 1))
    code, _, err = run(["bench", grown, "-o", out, "--resume", "-q"], capsys)
    assert code == 0, err
    rows = _records(out / "rows.jsonl")
    assert [r["key"] for r in rows] == ["s|vh|1|0", "s|vh|1|1"]
    assert set(json.loads((out / "experiment.json").read_text())["cells"]) == {"s|vh|1|0", "s|vh|1|1"}
    (out / "experiment.json").unlink()
    text = (out / "rows.jsonl").read_text().splitlines()
    (out / "rows.jsonl").write_text(text[0] + "\n" + text[1][:30])
    code, _, err = run(["bench", grown, "-o", out, "--resume", "-q"], capsys)
    assert code == 0, err
    assert [r["key"] for r in _records(out / "rows.jsonl")] == ["s|vh|1|0", "s|vh|1|1"]
    assert (out / "experiment.json").is_file()


# -- 2. documented usage: tree files, --library, another working folder ------------------------------------------

PILLAR = {"name": "test_resume_pillar", "params": [{"name": "h", "default": 1.0, "lo": 0.1, "hi": 3.0}],
          "tree": {"node": "translate", "params": {"y": {"mul": ["h", -0.5]}},
                   "children": [{"node": "cylinder", "params": {"radius": 0.3, "height": "h"}}]}}


@pytest.mark.parametrize("library", [False, True])
def test_a_tree_file_fit_resumes_from_another_working_folder(library, shared, tmp_path, capsys, monkeypatch):
    """``ipm fit TREE.json [--library DIR] --masks M -o RUN`` with relative paths, interrupted, then ``ipm fit
    --resume RUN`` from another working folder (without GEN or --library): the uninterrupted answer."""
    from ipm.sdf.node import NODES

    work = tmp_path / "work"
    (work / "lib").mkdir(parents=True)
    node = {"node": "test_resume_pillar", "params": {"h": 0.8}} if library else \
        {"node": "translate", "params": {"y": -0.3}, "children": [{"node": "cylinder", "params": {"radius": 0.3,
                                                                                                 "height": 0.8}}]}
    tree = {"tree": {"node": "union", "children": [node, {"node": "sphere", "params": {"radius": 0.4}}]}}
    (work / "tree.json").write_text(json.dumps(tree))
    (work / "lib" / "pillar.json").write_text(json.dumps(PILLAR))
    shutil.copytree(shared["masks"], work / "masks")
    lib = ["--library", "lib"] if library else []
    monkeypatch.chdir(work)
    try:
        args = ["fit", "tree.json", *lib, "--masks", "masks", "--budget", "24", "--discrete", "none", "-q"]
        code, _, err = run([*args, "-o", "whole"], capsys)
        assert code == 0, err
        code, _, err = run([*args, "-o", "run"], capsys)
        assert code == 0, err
        saved = json.loads((work / "run" / "settings.json").read_text())
        assert saved["source"] == str(work / "tree.json") and saved["target"]["masks"] == str(work / "masks")
        assert saved["library"] == ([str(work / "lib")] if library else None)
        _edit_records(work / "run" / "trajectory.jsonl", lambda r: r[:20])
        (work / "run" / "result.json").unlink()
        NODES.remove("test_resume_pillar")  # as in a new process: the macro comes from the run's library
        elsewhere = tmp_path / "elsewhere"
        elsewhere.mkdir()
        monkeypatch.chdir(elsewhere)
        code, _, err = run(["fit", "--resume", work / "run"], capsys)
        assert code == 0, err
        assert _result(work / "run") == _result(work / "whole")
        code, _, err = run(["fit", work / "tree.json", "--resume", work / "run", "-q"], capsys)  # GEN given too
        assert code == 0, err
        assert _result(work / "run") == _result(work / "whole")
    finally:
        NODES.remove("test_resume_pillar")


def test_the_api_resumes_without_the_generator(shared, tmp_path):
    import ipm

    run_dir = tmp_path / "run"
    shutil.copytree(shared["fit"], run_dir)
    result = ipm.fit(run_dir=run_dir, resume=True)
    assert result.params == json.loads((shared["fit"] / "result.json").read_text())["params"]


def test_a_structure_search_resumes_from_another_working_folder(shared, tmp_path, capsys, monkeypatch):
    work = tmp_path / "work"
    work.mkdir()
    shutil.copy(json.loads((shared["structure"] / "settings.json").read_text())["target"]["target_mesh"],
                work / "t.obj")
    monkeypatch.chdir(work)
    code, _, err = run(["fit", "--structure", "search", "--target-mesh", "t.obj", "--budget", STRUCTURE_BUDGET,
                        "-q", "-o", "run"], capsys)
    assert code == 0, err
    assert json.loads((work / "run" / "settings.json").read_text())["target"]["target_mesh"] == str(work / "t.obj")
    first = json.loads((work / "run" / "result.json").read_text())
    monkeypatch.chdir(tmp_path)
    code, _, err = run(["fit", "--resume", work / "run", "-q"], capsys)
    assert code == 0, err
    again = json.loads((work / "run" / "result.json").read_text())
    assert again["structure"] == first["structure"] and again["score"] == first["score"]


# -- 3. a full disk: no run folder left by a first run; a resume's folder stays resumable --------------------------

class _FullDisk:
    """Files opened for writing (``open``, ``io.open``: pathlib, PIL, trimesh, matplotlib) whose writes
    fail with ENOSPC from the ``n``-th on, counted over all of them."""

    def __init__(self, monkeypatch, n: int):
        self.n, self.count = n, 0
        real = builtins.open
        outer = self

        class File:
            def __init__(self, f):
                self._f = f

            def write(self, data):
                outer.count += 1
                if outer.count >= outer.n:
                    raise OSError(errno.ENOSPC, "No space left on device")
                return self._f.write(data)

            def __getattr__(self, name):
                return getattr(self._f, name)

            def __enter__(self):
                return self

            def __exit__(self, *exc):
                return self._f.__exit__(*exc)

            def __iter__(self):
                return iter(self._f)

        def fake_open(file, mode="r", *args, **kwargs):
            f = real(file, mode, *args, **kwargs)
            return File(f) if any(c in mode for c in "wax+") else f

        monkeypatch.setattr(builtins, "open", fake_open)
        monkeypatch.setattr(io, "open", fake_open)


@pytest.fixture(scope="module")
def fit_writes(shared, tmp_path_factory) -> int:
    mp = pytest.MonkeyPatch()
    try:
        disk = _FullDisk(mp, 10 ** 9)
        _ok(["fit", "dishes", "--masks", shared["masks"], "--budget", "24", "--discrete", "none", "-q",
             "-o", tmp_path_factory.mktemp("counted") / "run"])
    finally:
        mp.undo()
    assert disk.count > 30  # settings, trajectory lines, params, meshes, pictures, result
    return disk.count


@pytest.mark.parametrize("at", ["first", "second", "trajectory", "middle", "last"])
@pytest.mark.parametrize("existed", [False, True])
def test_a_full_disk_leaves_no_run_folder(at, existed, shared, fit_writes, tmp_path, capsys, monkeypatch):
    n = {"first": 1, "second": 2, "trajectory": 6, "middle": fit_writes // 2, "last": fit_writes}[at]
    out = tmp_path / "out"
    if existed:
        out.mkdir()
    _FullDisk(monkeypatch, n)
    code, stdout, err = run(["fit", "dishes", "--masks", shared["masks"], "--budget", "24", "--discrete", "none",
                             "-o", out], capsys)
    monkeypatch.undo()
    lines = err.strip().splitlines()
    assert code == 2, err
    assert len(lines) == 1 and lines[0].startswith(f"ipm: error: cannot write {out}"), err
    assert lines[0].endswith("no space left on the device") and stdout == ""
    assert (list(out.iterdir()) == []) if existed else not out.exists()
    assert [p.name for p in tmp_path.iterdir()] == (["out"] if existed else [])  # no staging folder either


@pytest.mark.parametrize("at", [1, 3, 12, 20])
def test_a_full_disk_keeps_a_resumed_run_resumable(at, shared, tmp_path, capsys, monkeypatch):
    run_dir = tmp_path / "run"
    shutil.copytree(shared["fit"], run_dir)
    for p in run_dir.iterdir():
        if p.name not in ("settings.json", "trajectory.jsonl"):
            p.unlink()
    _edit_records(run_dir / "trajectory.jsonl", lambda r: r[:25])
    before = _contents(run_dir)
    kept = _records(run_dir / "trajectory.jsonl")
    _FullDisk(monkeypatch, at)
    code, _, err = run(["fit", "--resume", run_dir], capsys)
    monkeypatch.undo()
    assert code == 2 and err.strip().startswith(f"ipm: error: cannot write {run_dir}"), err
    assert sorted(p.name for p in run_dir.iterdir()) == sorted(before)  # no final files, nothing removed
    assert (run_dir / "settings.json").read_text() == (shared["fit"] / "settings.json").read_text()
    assert _records(run_dir / "trajectory.jsonl")[:25] == kept
    code, _, err = run(["fit", "--resume", run_dir], capsys)
    assert code == 0, err
    assert _result(run_dir) == _result(shared["fit"])


def test_a_full_disk_in_a_structure_search_leaves_no_run_folder(shared, tmp_path, capsys, monkeypatch):
    mesh = json.loads((shared["structure"] / "settings.json").read_text())["target"]["target_mesh"]
    out = tmp_path / "out"
    _FullDisk(monkeypatch, 4)
    code, _, err = run(["fit", "--structure", "search", "--target-mesh", mesh, "--budget", STRUCTURE_BUDGET,
                        "-o", out], capsys)
    monkeypatch.undo()
    assert code == 2 and err.strip().startswith(f"ipm: error: cannot write {out}"), err
    assert list(tmp_path.iterdir()) == []


def test_an_interrupted_first_run_is_kept_to_resume(shared, tmp_path, capsys, monkeypatch):
    """Ctrl-C is not a failure: the first run's folder stays, and resumes to the uninterrupted answer."""
    from ipm.optim.evaluator import Evaluator

    real = Evaluator._evaluate

    def interrupted(self, *a):
        if self.count == 20:
            raise KeyboardInterrupt
        return real(self, *a)

    run_dir = tmp_path / "run"
    with monkeypatch.context() as m:
        m.setattr(Evaluator, "_evaluate", interrupted)
        code, _, err = run(["fit", "dishes", "--masks", shared["masks"], "--budget", FIT_BUDGET, "--discrete",
                            "none", "-o", run_dir], capsys)
    assert code == 130 and "interrupted" in err
    assert len(_records(run_dir / "trajectory.jsonl")) == 20 and not (run_dir / "result.json").exists()
    code, _, err = run(["fit", "--resume", run_dir], capsys)
    assert code == 0, err
    assert _result(run_dir) == _result(shared["fit"])
