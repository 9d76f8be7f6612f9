"""The bench method registry (ipm/bench/methods/): one file per method, found by name, settings
checked up front by :func:`check_settings` with the same parser the method runs with."""

from __future__ import annotations

import pytest
from conftest import throwaway_member

from ipm.bench.methods import METHODS, check_settings
from ipm.errors import InputError


def test_every_method_is_one_module_of_the_package():
    assert set(METHODS.names()) >= {"ipm", "visual-hull", "sdf-grid", "mesh-deform", "bsp", "perturb"}
    for name in ("ipm", "visual-hull", "sdf-grid", "mesh-deform", "bsp", "perturb"):
        assert METHODS[name].__module__ == "ipm.bench.methods." + name.replace("-", "_")


@pytest.mark.parametrize("method, settings, key, allowed", [
    ("sdf-grid", {"resolutoin": 32}, "resolutoin", "expected one of: band"),
    ("mesh-deform", {"lr": "fast"}, "lr", r"expected a number in \[1e-06, 1.0\], got 'fast'"),
    ("bsp", {"planes": 0}, "planes", r"expected an integer in \[1, 4096\], got 0"),
    ("perturb", {"max_functions": 2.5}, "max_functions", "expected an integer"),
    ("visual-hull", {"resolution": True}, "resolution", "expected an integer"),
    ("visual-hull", {"resolutoin": 24}, "resolutoin", "expected one of: resolution"),
    ("ipm", {"generator": "dishes", "lrr": 0.1}, "lrr", "expected some of: .*generator"),
    ("ipm", {"generator": "dishes", "lr": "fast"}, "lr", r"expected a learning rate in \(0, 1\], got 'fast'"),
    ("ipm", {"generator": "dishes", "lr": 5.0}, "lr", r"expected a learning rate in \(0, 1\]"),
    ("ipm", {"generator": "dishes", "max_size": 2}, "max_size", r"expected an integer in \[8, 4096\]"),
    ("ipm", {"generator": "no-such-generator"}, "generator", "unknown generator 'no-such-generator'"),
    ("ipm", {"generator": "dishes", "preset": "saucepan"}, "preset", "expected one of .*mug.*got 'saucepan'"),
    ("ipm", {"preset": "mug"}, "generator", "expected a generator name"),
])
def test_bad_settings_are_refused_up_front(method, settings, key, allowed):
    with pytest.raises(InputError, match=f"{method}: .*{key}.*{allowed}"):
        check_settings(method, settings)


def test_good_settings_pass_and_unknown_methods_are_refused():
    check_settings("ipm", {"generator": "dishes", "preset": "mug", "discrete": "none", "max_size": 64, "lr": 0.05})
    check_settings("sdf-grid", {"resolution": 24, "lr": 1})  # an integer is a number
    check_settings("visual-hull", {})
    with pytest.raises(InputError, match="unknown bench method 'sdf_grid'; known: .*sdf-grid"):
        check_settings("sdf_grid", {})


THROWAWAY = '''
    """A throwaway bench method: an axis-aligned box of half side ``half`` around the origin."""
    import msgspec
    import torch

    from ipm.bench.methods import Prediction, method
    from ipm.types import TriMesh


    class BoxSettings(msgspec.Struct, frozen=True, forbid_unknown_fields=True):
        half: float = 0.5


    @method("throwaway-box", BoxSettings)
    def box(task, s, budget, seed):
        import trimesh

        m = trimesh.creation.box(extents=(2 * s.half,) * 3)
        return Prediction(TriMesh(torch.as_tensor(m.vertices), torch.as_tensor(m.faces)), 1, 0.0)
'''


def test_a_method_in_another_package_is_found_and_runs_in_the_harness(tmp_path, monkeypatch):
    from ipm.bench import harness
    from ipm.bench.config import load_experiment

    with throwaway_member(METHODS, "throwaway-box", THROWAWAY, tmp_path, monkeypatch, "ipm_throwaway_methods"):
        assert "throwaway-box" in METHODS
        with pytest.raises(InputError, match="throwaway-box: setting half: expected a number, got 'big'"):
            check_settings("throwaway-box", {"half": "big"})
        exp = tmp_path / "proj" / "experiments" / "e.toml"
        exp.parent.mkdir(parents=True)
        exp.write_text('name = "e"\nviews = [2]\nsize = 64\nheldout_size = 64\nsamples = 2000\n'
                       'iou_resolution = 24\n[[targets]]\nname = "mug"\ngenerator = "dishes"\npreset = "mug"\n'
                       '[[methods]]\nname = "box"\nmethod = "throwaway-box"\nhalf = 0.4\n')
        row = harness.run_cell(str(exp.resolve()), load_experiment(exp).cells()[0])
        assert row["status"] == "ok" and row["method"] == "box" and 0.0 < row["heldout_iou"] < 1.0, row


def test_evaluations_to_final_counts_up_to_the_first_record_near_the_final_iou():
    """The first evaluation whose mean input-view IoU is within 0.01 of the final point's, counted from 1; the final
    point is found by its exact values (the last record at it), whatever its place in the run."""
    import torch

    from ipm.bench.methods.ipm import evaluations_to_final

    def rec(i, x, iou, d=1):
        return {"i": i, "x": [float(v) for v in x], "discrete": {"n": d}, "iou": iou}

    final = torch.tensor([0.25, 0.5], dtype=torch.float64)
    records = [rec(0, [0.0, 0.0], [0.50, 0.70]), rec(1, [0.1, 0.0], [0.90, 0.95]),  # mean 0.925: not yet
               rec(2, [0.2, 0.0], [0.93, 0.94]),  # 0.935: within 0.01 of 0.94
               rec(3, [0.25, 0.5], [0.94, 0.94]), rec(4, [0.3, 0.0], [0.20, 0.20])]
    assert evaluations_to_final(records, final, {"n": 1}) == 3
    assert evaluations_to_final(records, final, {"n": 1}, near=0.0) == 4
    assert evaluations_to_final(records, final, {"n": 2}) is None  # not a point of the run
    assert evaluations_to_final([{**r, "iou": []} for r in records], final, {"n": 1}) is None
