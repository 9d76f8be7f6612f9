"""Cues beyond silhouettes in the bench (issue #13): a method's ``cues`` setting, the depth maps and part
labels the harness renders of the input views (checked against the deferred renderer), the ipm method
passing them into the fit's target, bad settings refused up front, and a tiny cue experiment end to end."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest
import torch
from conftest import run_cli

from ipm.bench import harness
from ipm.bench.config import load_experiment
from ipm.bench.methods import METHODS, Cues, Task, check_settings, requested_cues
from ipm.errors import InputError

HEAD = 'name = "e"\nsize = 48\nheldout_size = 32\nsamples = 500\niou_resolution = 16\nbudget = 6\n'
TARGETS = ('[[targets]]\nname = "house"\ngenerator = "building"\npreset = "house2"\n'
           '[[targets]]\nname = "mug"\ngenerator = "dishes"\npreset = "mug"\n'
           'params = { handle_azimuth = -60.0 }\n')


def experiment(tmp_path: Path, text: str, head: str = HEAD, targets: str = TARGETS) -> Path:
    path = tmp_path / "proj" / "experiments" / "e.toml"
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text(head + targets + text)
    return path


VH = '[[methods]]\nname = "vh"\nmethod = "visual-hull"\nresolution = 16\n'


@pytest.mark.parametrize("target, parts", [("house", ("windows", "roof")), ("mug", ("handle",))])
def test_cues_are_the_deferred_renderers_depth_and_the_generators_groups(tmp_path, target, parts):
    """Depth maps of a generator target equal the deferred renderer's depth at the input cameras (NaN off
    the object); a pixel is labelled ``k`` exactly where the deferred renderer's visible face is in the
    group ``parts[k]``; the masks are the ones every method sees."""
    from ipm.render.deferred import render_deferred

    exp = str(experiment(tmp_path, VH).resolve())
    seen = harness.target_views(exp, target, 2, Cues(depth=True, parts=parts))
    mesh = harness.load_target(exp, target).mesh
    assert np.array_equal(seen.masks, harness.target_masks(exp, target, 2))
    assert seen.part_names == parts and seen.depth.dtype == np.float64 and seen.parts.dtype == np.int64
    for i, cam in enumerate(harness._input_cameras(load_experiment(exp), 2)):
        d = render_deferred(mesh, cam)
        on = d.raster.mask.numpy()
        assert np.array_equal(on, seen.masks[i])
        assert np.isnan(seen.depth[i][~on]).all() and np.isfinite(seen.depth[i][on]).all()
        np.testing.assert_allclose(seen.depth[i][on], d.depth.numpy()[on], rtol=1e-9, atol=1e-12)
        group = np.array(mesh.group_names + ("(none)",))[d.parts.numpy()]  # -1 (empty): "(none)"
        for k, name in enumerate(parts):
            assert np.array_equal(seen.parts[i] == k, group == name), (i, name)
            assert (seen.parts[i] == k).sum() > 0, f"{name} not seen in view {i}"
        assert np.array_equal(seen.parts[i] == -1, ~np.isin(group, parts))


def test_depth_of_a_mesh_file_target(tmp_path):
    """Mesh files give depth too (no part labels): the same exact rasterization as their masks."""
    from ipm.generators import get_generator
    from ipm.io.export import export_mesh

    gen = get_generator("dishes")
    export_mesh(gen.to_mesh(gen.values("teacup")), tmp_path / "cup.ply", sidecar=False)
    exp = str(experiment(tmp_path, VH, targets=f'[[targets]]\nname = "cup"\nmesh = "{tmp_path / "cup.ply"}"\n')
              .resolve())
    seen = harness.target_views(exp, "cup", 1, Cues(depth=True))
    assert seen.parts is None and np.array_equal(np.isfinite(seen.depth), seen.masks)
    assert 2.0 < np.nanmin(seen.depth) < np.nanmax(seen.depth) < 4.4  # the unit sphere at distance 3.2


def test_methods_get_only_the_cues_they_ask_for(tmp_path):
    """A method asks for cues with a ``cues`` setting (parsed by parse_cues); the harness renders those for
    its task and nothing for a method without one."""
    from types import SimpleNamespace

    from ipm.bench.methods import Method, parse_cues

    assert requested_cues("visual-hull", {}) == Cues() and not Cues()
    assert requested_cues("ipm", {"generator": "dishes"}) == Cues()
    c = requested_cues("ipm", {"generator": "building", "cues": ["parts:windows", "depth"]})
    assert c == Cues(True, ("windows",)) and c.names() == ["depth", "parts:windows"]
    assert requested_cues("ipm", {"generator": "dishes", "cues": ["parts"]}).parts == ("body", "handle", "spout",
                                                                                        "knob")

    got = {}

    def spy(task, settings, budget, seed):
        got[settings.cues] = task
        raise harness.MethodFailed("spied")

    def parse(name, settings):
        return SimpleNamespace(cues=parse_cues(name, settings.get("cues", []), ("walls", "windows", "roof")))

    METHODS.add("_cue_spy", Method("_cue_spy", spy, parse))
    try:
        exp = experiment(tmp_path, '[[methods]]\nname = "plain"\nmethod = "_cue_spy"\ntargets = ["house"]\n'
                         '[[methods]]\nname = "windows"\nmethod = "_cue_spy"\ncues = ["parts:windows"]\n'
                         'targets = ["house"]\n'
                         '[[methods]]\nname = "all"\nmethod = "_cue_spy"\ncues = ["depth", "parts"]\n'
                         'targets = ["house"]\n')
        for cell in load_experiment(exp).cells():
            assert harness.run_cell(str(exp.resolve()), cell)["status"] == "failed"
    finally:
        METHODS.remove("_cue_spy")
    plain, windows, every = got[Cues()], got[Cues(parts=("windows",))], got[Cues(True, ("walls", "windows", "roof"))]
    assert plain.depth is None and plain.parts is None and plain.part_names == ()
    assert windows.depth is None and windows.part_names == ("windows",) and set(np.unique(windows.parts)) == {-1, 0}
    assert every.depth is not None and set(np.unique(every.parts)) == {-1, 0, 1, 2}
    # windows are the same pixels whichever other parts are named
    assert np.array_equal(windows.parts == 0, every.parts == 1)


def test_the_ipm_method_passes_the_cues_into_the_fits_target(monkeypatch):
    """Full size: the maps as they are; under max_size: reduced with the masks (mean depth of a block's
    readings, its most common label)."""
    import ipm.optim.fit as fit

    seen = []

    def fake_run_fit(gen, target, settings, **kw):  # sink: the bench keeps the records
        seen.append(target)
        raise MethodFailed_("stop")

    class MethodFailed_(Exception):
        pass

    monkeypatch.setattr(fit, "run_fit", fake_run_fit)
    from ipm.bench.methods.ipm import IpmSettings
    from ipm.render.camera import input_views

    masks = np.zeros((1, 16, 16), bool)
    masks[0, 4:12, 4:12] = True
    depth = np.where(masks, 3.0, np.nan)
    depth[0, 4:6, 4:6] = np.array([[2.0, 3.0], [np.nan, 4.0]])
    parts = np.full(masks.shape, -1)
    parts[0, 4:7, 4:6] = 0
    task = Task(masks, input_views(1, 16), depth, parts, ("windows",))
    s = METHODS["ipm"].parse("ipm", {"generator": "building", "cues": ["depth", "parts:windows"]})
    assert isinstance(s, IpmSettings)
    for max_size in (None, 8):
        with pytest.raises(MethodFailed_):
            METHODS["ipm"].run(task, IpmSettings(s.generator, max_size, s.fit, s.cues), 5, 0)
    full, half = seen
    assert full.part_names == ("windows",) and full.depth.dtype == torch.float32
    assert torch.equal(torch.isnan(full.depth), torch.as_tensor(np.isnan(depth)))
    assert torch.equal(full.parts, torch.as_tensor(parts))
    assert half.masks.shape == half.depth.shape == half.parts.shape == (1, 8, 8)
    assert float(half.depth[0, 2, 2]) == pytest.approx(3.0)  # (2 + 3 + 4) / 3: the NaN is no reading
    assert torch.isnan(half.depth[0, 0, 0]) and int(half.parts[0, 0, 0]) == -1
    assert half.parts[0, 2:4, 2].tolist() == [0, -1]  # block rows 4-5: all windows; 6-7: one row of two


BAD = [
    ('method = "ipm"\ngenerator = "building"\ncues = ["colour"]', "house",
     r"ipm: setting cues: expected a list of depth, parts \(every part\) or parts:NAME \(NAME one of walls, "
     r"windows, balconies, doors, roof\), got \['colour'\]"),
    ('method = "ipm"\ngenerator = "building"\ncues = "depth"', "house", "setting cues: expected a list of"),
    ('method = "ipm"\ngenerator = "building"\ncues = ["parts:chimney"]', "house",
     r"setting cues: .*NAME one of walls.*got \['parts:chimney'\]: 'parts:chimney' is not one of these"),
    ('method = "ipm"\ngenerator = "dishes"\ncues = ["depth", "depth"]', "mug", "depth given twice"),
    ('method = "ipm"\ngenerator = "sdftree"\ncues = ["depth"]', "mug",
     "setting cues: expected none for the SDF generator sdftree"),
    ('method = "visual-hull"\ncues = ["depth"]', "mug", "visual-hull: unknown setting 'cues'; expected one of: "
     "resolution"),
    ('method = "ipm"\ngenerator = "dishes"\ncues = ["parts:handle"]', "house",
     r"target house: setting cues: expected parts of building \(walls, .*\), got handle"),
    ('method = "ipm"\ngenerator = "dishes"\ncues = ["parts:handle"]', "cup",
     "target cup: setting cues: expected parts of a generator target, got parts:handle for the mesh file"),
]


@pytest.mark.parametrize("method, target, message", BAD)
def test_bad_cue_settings_are_refused_before_any_cell(tmp_path, method, target, message):
    extra = '[[targets]]\nname = "cup"\nmesh = "cup.ply"\n'
    exp = experiment(tmp_path, f'[[methods]]\nname = "m"\n{method}\ntargets = ["{target}"]\n',
                     targets=TARGETS + extra)
    with pytest.raises(InputError, match=message):
        load_experiment(exp)


def test_a_bad_cue_setting_is_one_line_and_exit_2(tmp_path, capsys):
    exp = experiment(tmp_path, '[[methods]]\nname = "m"\nmethod = "ipm"\ngenerator = "dishes"\n'
                     'cues = ["normals"]\n')
    code, out, err = run_cli(["bench", exp, "-o", tmp_path / "res"], capsys)
    lines = err.strip().splitlines()
    assert code == 2 and len(lines) == 1, err
    assert "method m" in lines[0] and "setting cues" in lines[0] and "'normals' is not one of these" in lines[0]
    assert not (tmp_path / "res").exists()


def test_check_settings_knows_the_cue_setting():
    check_settings("ipm", {"generator": "building", "cues": ["depth", "parts:windows", "parts:doors"]})
    with pytest.raises(InputError, match="part windows given twice"):
        check_settings("ipm", {"generator": "building", "cues": ["parts", "parts:windows"]})


def test_a_tiny_cue_experiment_end_to_end(tmp_path, capsys):
    """A dishes fit given depth and one given handle labels next to the silhouette-only fit: rows say which
    cues each was given, the tables list the cue rows with parameter error and discrete accuracy, and the
    hidden parts are those of what each was given (the mug's handle points at the camera)."""
    fit = 'method = "ipm"\ngenerator = "dishes"\ndiscrete = "none"\nviews = [1]\ntargets = ["mug"]\n'
    exp = experiment(tmp_path, f'[[methods]]\nname = "fit"\n{fit}'
                     f'[[methods]]\nname = "fit+depth"\n{fit}cues = ["depth"]\n'
                     f'[[methods]]\nname = "fit+handle"\n{fit}cues = ["parts:handle"]\n',
                     head=HEAD.replace("size = 48", "size = 40"))
    out = tmp_path / "res"
    code, _, err = run_cli(["bench", exp, "-o", out, "--json"], capsys)
    assert code == 0, err
    rows = {r["method"]: r for r in map(json.loads, (out / "rows.jsonl").read_text().splitlines())}
    assert all(r["status"] == "ok" for r in rows.values()), rows
    assert len({r["evaluations"] for r in rows.values()}) == 1  # the same budget
    assert "cues" not in rows["fit"]
    assert rows["fit+depth"]["cues"] == ["depth"] and rows["fit+handle"]["cues"] == ["parts:handle"]
    assert all("param_error" in r and "discrete_accuracy" in r for r in rows.values())
    table = (out / "table.md").read_text()
    section = table[table.index("### param. error"):table.index("### discrete acc.")]
    assert "| fit+depth | 1 |" in section and "| fit+handle | 1 |" in section
    # the handle points at the input camera: inside the silhouette, but plain in depth and in its labels
    # (a lid knob of the default size would stand inside the mug's opening, below the rim: hidden in the
    # silhouette and in the handle's labels, plain in the depth seen from above)
    assert rows["fit"]["hidden_discrete"] == {"has_handle": [0], "has_knob": [1]}
    assert rows["fit+depth"]["hidden_discrete"] == {}
    assert rows["fit+handle"]["hidden_discrete"] == {"has_knob": [1]}
    assert "- mug, 1 view: has_handle (also 0)" in table
    assert "- mug, 1 view with depth: none" in table and "- mug, 1 view with parts:handle: has_knob (also 1)" in table
