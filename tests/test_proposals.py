"""Learned proposals (ipm.proposals): what the network sees, the yaw convention against the fit's pose, the
most probable combinations, training that resumes bit for bit, weights files refused with one line, and the
shipped networks against chance on held-out generator samples."""

from __future__ import annotations

import itertools
import json
import math

import numpy as np
import pytest
import torch

from ipm.errors import InputError
from ipm.generators import get_generator
from ipm.optim.settings import FitSettings
from ipm.proposals import load_proposer, shipped
from ipm.proposals.data import Samples, augment, make_samples, render_sample, yaw_bin
from ipm.proposals.encode import TRAIN_AZIMUTH, camera_azimuth, crop_box, encode_mask
from ipm.proposals.net import NetConfig, ProposalNet, load_weights, save_weights
from ipm.proposals.propose import _most_probable
from ipm.proposals.train import HELDOUT_SEED, TrainSettings, evaluate, train
from ipm.render.camera import orbit_camera
from tests.conftest import run_cli


def _iou(a: torch.Tensor, b: torch.Tensor) -> float:
    a, b = a > 0.5, b > 0.5
    return float((a & b).sum()) / max(float((a | b).sum()), 1.0)


def test_the_encoding_ignores_where_the_object_is_and_how_large():
    big = torch.zeros(120, 160)
    big[20:100, 40:80] = 1  # 80 tall, 40 wide
    small = torch.zeros(64, 64)
    small[40:60, 5:15] = 1  # the same shape, a quarter the size, elsewhere
    cx, cy, side = crop_box(big)
    assert (cx, cy) == (60.0, 60.0) and side == pytest.approx(80 / (1 - 2 * 0.08))
    a, b = encode_mask(big), encode_mask(small)
    assert a.shape == (1, 64, 64)
    assert _iou(a[0], b[0]) > 0.9
    with pytest.raises(InputError, match="expected a mask with some foreground"):
        encode_mask(torch.zeros(8, 8))


@pytest.mark.parametrize("az", [-150.0, 0.0, 30.0, 97.5])
def test_camera_azimuth_is_orbit_cameras_own(az):
    assert camera_azimuth(orbit_camera(az, 20.0, 3.0)) == pytest.approx(az, abs=1e-9)


def test_a_sample_turned_by_a_yaw_is_what_the_fit_renders_at_that_yaw():
    """The training renders turn the shape the way the fit's pose does (a handle on the other side would not
    match): the fit's own mesh at yaw 70, cropped, against the training render at yaw 70."""
    from ipm.optim.problem import Problem
    from ipm.optim.targets import MaskTarget
    from ipm.render.raster import rasterize_mesh

    gen = get_generator("dishes")
    values = gen.values("mug")
    cam = orbit_camera(TRAIN_AZIMUTH, 25.0, 3.2, width=96)
    mask = render_sample(gen, values, 70.0, 25.0, 3.2)
    prob = Problem(gen, MaskTarget(mask[None].double(), [cam]), FitSettings(preset="mug"), dtype=torch.float64)
    scores = {}
    for yaw in (70.0, -70.0, 110.0):
        mesh = prob.mesh_world(prob.x0(yaw=yaw, scale=0.8), prob.d0, pose_grad=False)
        scores[yaw] = _iou(encode_mask(rasterize_mesh(mesh, cam).mask)[0], encode_mask(mask)[0])
    assert scores[70.0] > 0.95
    assert scores[70.0] > max(scores[-70.0], scores[110.0]) + 0.03


def test_the_most_probable_combinations_come_in_order():
    probs = [torch.tensor([0.1, 0.6, 0.3]), torch.tensor([0.8, 0.2]), torch.tensor([0.5, 0.25, 0.25])]
    brute = sorted(((float(probs[0][i] * probs[1][j] * probs[2][k]), (i, j, k))
                    for i, j, k in itertools.product(range(3), range(2), range(3))), key=lambda e: -e[0])
    got = list(_most_probable(probs, 5))
    assert [p for p, _ in got] == pytest.approx([p for p, _ in brute[:5]])
    assert got[0][1] == (1, 0, 0)
    assert list(_most_probable([], 3)) == [(1.0, ())]


def test_the_yaw_lies_between_the_peak_bin_and_its_neighbours():
    from ipm.proposals.net import YAW_BINS
    from ipm.proposals.propose import peak_yaw

    step = 360.0 / YAW_BINS

    def probs(weights: dict) -> torch.Tensor:
        p = torch.full((YAW_BINS,), 1e-9, dtype=torch.float64)
        for k, w in weights.items():
            p[k % YAW_BINS] = w
        return p / p.sum()

    assert peak_yaw(probs({5: 0.8, 4: 0.1, 6: 0.1})) == pytest.approx(5 * step, abs=1e-6)
    assert peak_yaw(probs({5: 0.45, 6: 0.45})) == pytest.approx(5.5 * step, abs=1e-6)  # half way between
    mid = peak_yaw(probs({5: 0.6, 6: 0.3}))
    assert 5 * step < mid < 5.5 * step
    # across 0: the neighbour below bin 0 is the last bin
    assert peak_yaw(probs({0: 0.45, -1: 0.45})) == pytest.approx(360.0 - step / 2, abs=1e-6)
    # a second peak half way round (a shape alike turned by 180 degrees) is left out, not averaged in
    assert peak_yaw(probs({3: 0.5, 3 + YAW_BINS // 2: 0.45})) == pytest.approx(3 * step, abs=1e-6)


def test_augmentations_are_a_function_of_their_seed_and_keep_the_object():
    gen = get_generator("dishes")
    data = make_samples(gen, 6, seed=3)
    a = augment(data.inputs(), torch.Generator().manual_seed(7))
    b = augment(data.inputs(), torch.Generator().manual_seed(7))
    assert torch.equal(a, b)
    ious = [_iou(x[0], y[0]) for x, y in zip(a, data.inputs())]
    assert min(ious) > 0.6 and float(np.mean(ious)) > 0.8


def _tiny(gen) -> Samples:
    return make_samples(gen, 24, seed=1)


def test_training_resumed_from_a_checkpoint_ends_bit_identical(tmp_path):
    gen = get_generator("dishes")
    data = _tiny(gen)
    s = TrainSettings(samples=24, steps=6, batch=8, seed=2)
    whole = train(gen, s, checkpoint=tmp_path / "a.npz", every=3, data=data)
    partial = TrainSettings(samples=24, steps=6, batch=8, seed=2)
    with pytest.raises(_Stop):  # interrupted after step 3 (the checkpoint holds step 3)
        train(gen, partial, checkpoint=tmp_path / "b.npz", every=3, data=data, progress=_stop_after(3))
    resumed = train(gen, partial, checkpoint=tmp_path / "b.npz", every=3, resume=True, data=data)
    for (k, v), (_, w) in zip(whole.state_dict().items(), resumed.state_dict().items()):
        assert torch.equal(v, w), k
    with pytest.raises(InputError, match="other settings"):
        train(gen, TrainSettings(samples=24, steps=7, batch=8, seed=2), checkpoint=tmp_path / "b.npz", resume=True,
              data=data)


class _Stop(Exception):
    pass


def _stop_after(n: int):
    def progress(stage, done, total, loss):
        if stage == "train" and done == n:
            raise _Stop
    return progress


def test_weights_for_other_parameters_are_refused_with_one_line(tmp_path):
    dishes, building = get_generator("dishes"), get_generator("building")
    path = save_weights(ProposalNet(NetConfig.for_generator(dishes)), tmp_path / "d.npz")
    net, _ = load_weights(path, dishes)
    assert net.config.generator == "dishes"
    with pytest.raises(InputError, match=r"trained for dishes's parameters .* expected weights made by "
                                         r"ipm train-proposals building"):
        load_proposer(building, path)
    (tmp_path / "junk.npz").write_bytes(b"not a zip")
    with pytest.raises(InputError, match="no .npz"):
        load_weights(tmp_path / "junk.npz")
    np.savez(tmp_path / "noconf.npz", a=np.zeros(3))
    with pytest.raises(InputError, match="expected a config entry"):
        load_weights(tmp_path / "noconf.npz")


def test_old_runs_resume_without_proposals():
    from ipm.fitting import _settings_from_json

    assert _settings_from_json({"budget": 10}).init == "presets"
    assert _settings_from_json({"budget": 10, "init": "both"}).init == "both"


def test_a_fit_that_asks_for_learned_starts_without_weights_is_refused(tmp_path, capsys):
    masks = tmp_path / "m"
    code, _, err = run_cli(["render", "mug", "--views", "1", "--size", "48", "--no-previews", "-o", str(masks)], capsys)
    assert code == 0, err
    code, out, err = run_cli(["fit", "mug", "--masks", str(masks), "--init", "learned", "--budget", "3",
                              "-o", str(tmp_path / "run")], capsys)
    assert code == 2 and err.count("\n") == 1 and "expected proposal weights for mug" in err
    assert not (tmp_path / "run").exists()
    code, _, err = run_cli(["fit", "mug", "--masks", str(masks), "--init", "sometimes", "--budget", "3",
                            "-o", str(tmp_path / "run")], capsys)
    assert code == 2 and "init" in err and "both" in err


def test_a_fit_started_from_proposals_says_so(tmp_path, capsys):
    """A network trained for two steps (its proposals are poor, but they are proposals): the fit records them in
    result.json, and looks at them (trajectory phase init:learned) beside the presets, or in their place."""
    gen = get_generator("dishes")
    net = train(gen, TrainSettings(samples=24, steps=2, batch=8), data=_tiny(gen))
    weights = save_weights(net, tmp_path / "w.npz")
    masks = tmp_path / "m"
    code, _, err = run_cli(["render", "dishes", "--preset", "mug", "--views", "1", "--size", "48", "--no-previews",
                            "-o", str(masks)], capsys)
    assert code == 0, err
    for init in ("both", "learned"):
        run = tmp_path / f"run_{init}"
        code, _, err = run_cli(["fit", "dishes", "--masks", str(masks), "--init", init, "--proposals", str(weights),
                                "--budget", "40", "-o", str(run)], capsys)
        assert code == 0, err
        start = json.loads((run / "result.json").read_text())["start"]
        assert start["init"] == init and 1 <= len(start["proposals"]) <= 4
        assert all(set(p["discrete"]) == {"has_handle", "has_spout", "has_knob"} for p in start["proposals"])
        phases = [json.loads(line)["phase"] for line in (run / "trajectory.jsonl").read_text().splitlines()]
        assert "init:learned" in phases
    # presets: no proposals looked at
    run = tmp_path / "run_presets"
    code, _, err = run_cli(["fit", "dishes", "--masks", str(masks), "--init", "presets", "--budget", "20",
                            "-o", str(run)], capsys)
    assert code == 0, err
    assert json.loads((run / "result.json").read_text())["start"] == {"init": "presets"}
    # without --init the run records the generator's start, not "the default", which a later version may change
    run = tmp_path / "run_default"
    code, _, err = run_cli(["fit", "dishes", "--masks", str(masks), "--budget", "5", "-o", str(run)], capsys)
    assert code == 0, err
    assert json.loads((run / "settings.json").read_text())["settings"]["init"] == "presets"


@pytest.mark.parametrize("name", sorted(shipped()))
def test_shipped_networks_beat_chance_on_held_out_samples(name):
    """Samples from the held-out seed, which no training run draws: no discrete head worse than always guessing
    the most frequent value (within sampling noise), one at least 10 points better, the continuous parameters
    closer than their mean, the yaw nearer than chance."""
    gen = get_generator(name)
    net, extra = load_weights(shipped()[name], gen)
    scores = evaluate(net, make_samples(gen, 100, HELDOUT_SEED))
    # most of a building's sizes (windows, balconies, doors) do not show in a 64 px silhouette: on average the
    # network is only a little closer than the mean; what shows it reads well (the heads below)
    assert scores["continuous_mae"] < scores["continuous_mae_of_the_mean"]
    for head, s in scores["discrete"].items():
        assert s["accuracy"] >= s["chance"] - 0.05, head
    assert max(s["accuracy"] - s["chance"] for s in scores["discrete"].values()) > 0.1
    assert scores["yaw_within_one_bin"] > 1.5 * scores["yaw_chance"]
    assert json.loads(str(extra["settings"]))["seed"] != HELDOUT_SEED
    assert yaw_bin(360.0) == yaw_bin(0.0) == 0 and math.isfinite(scores["continuous_mae"])


def test_the_proposal_bench_method_poses_the_guess_with_its_budget_in_looks():
    """The ``proposal`` baseline with the shipped dishes network: its best guess, scaled and placed by one look
    (budget 2), not refined, lies on the input mask of the mug; with budget 6, three looks in a row place the same
    guess at least as well, its parameters unchanged."""
    from ipm.bench.methods import METHODS, Task
    from ipm.metrics import unit_sphere_frame
    from ipm.render.camera import input_views
    from ipm.render.raster import rasterize

    gen = get_generator("dishes")
    mesh = gen.to_mesh(gen.values("mug"))
    center, scale = unit_sphere_frame(mesh.verts.double().numpy())
    V = (mesh.verts.double() - torch.as_tensor(center)) * scale
    cams = input_views(1, 96)
    masks = torch.stack([rasterize(V, mesh.faces, c).mask for c in cams]).float()
    settings = METHODS["proposal"].parse("proposal", {"generator": "dishes"})
    pred = METHODS["proposal"](Task(masks, cams), settings, 2, 0)
    assert pred.evaluations == 2 and pred.info["discrete"] == {"has_handle": 1, "has_spout": 0, "has_knob": 0}
    seen = rasterize(pred.mesh.verts, pred.mesh.faces, cams[0]).mask
    assert _iou(seen.float(), masks[0]) > 0.75
    three = METHODS["proposal"](Task(masks, cams), settings, 6, 0)
    assert three.evaluations == 6 and three.info["params"] == pred.info["params"]
    seen3 = rasterize(three.mesh.verts, three.mesh.faces, cams[0]).mask
    assert _iou(seen3.float(), masks[0]) >= _iou(seen.float(), masks[0]) - 1e-6


def test_damaged_weights_and_checkpoints_are_bad_input(tmp_path):
    gen = get_generator("dishes")
    good = save_weights(ProposalNet(NetConfig.for_generator(gen)), tmp_path / "w.npz")
    (tmp_path / "cut.npz").write_bytes(good.read_bytes()[:3000])  # a truncated zip
    with pytest.raises(InputError, match="cut.npz"):
        load_weights(tmp_path / "cut.npz")
    arrays = dict(np.load(good))
    arrays["config"] = np.array(json.dumps({**json.loads(str(arrays["config"])), "size": 1e400}))
    np.savez(tmp_path / "huge.npz", **arrays)
    with pytest.raises(InputError, match="expected a config entry"):
        load_weights(tmp_path / "huge.npz")
    data = _tiny(gen)
    s = TrainSettings(samples=24, steps=4, batch=8)
    train(gen, s, checkpoint=tmp_path / "c.npz", every=2, data=data)
    ck = dict(np.load(tmp_path / "c.npz"))
    for key, value, match in (("settings", np.array("{not json"), "expected a checkpoint's settings"),
                              ("step", np.array(-3), "expected a step from 0 to 4"),
                              ("adam.m.yaw.bias", np.zeros(3, dtype=np.float32), "Adam's state of yaw.bias")):
        np.savez(tmp_path / "bad.npz", **{**ck, key: value})
        with pytest.raises(InputError, match=match):
            train(gen, s, checkpoint=tmp_path / "bad.npz", resume=True, data=data)


def test_the_training_data_are_the_same_for_any_worker_count(monkeypatch):
    """Chunk c draws from the seed and c alone: two processes draw what one does, in the same order, and a longer
    data set of the same seed begins with a shorter one."""
    from ipm.proposals import data as D

    monkeypatch.setattr(D, "CHUNK", 3)
    gen = get_generator("dishes")
    seen = []
    one = D.make_samples(gen, 8, seed=5, progress=lambda i, n: seen.append((i, n)))
    two = D.make_samples(gen, 8, seed=5, workers=2)
    short = D.make_samples(gen, 4, seed=5)
    assert seen == [(3, 8), (6, 8), (8, 8)] and one.masks.dtype == torch.uint8
    for a, b, c in zip((one.masks, one.continuous, one.discrete, one.yaw), (two.masks, two.continuous, two.discrete,
                       two.yaw), (short.masks, short.continuous, short.discrete, short.yaw)):
        assert torch.equal(a, b) and torch.equal(a[:4], c)
    assert not torch.equal(one.masks[:3], one.masks[3:6])  # chunks draw different samples
    other = D.make_samples(gen, 3, seed=6)
    assert not torch.equal(other.continuous, one.continuous[:3])


def test_a_generator_whose_renders_never_fit_the_image_is_refused(monkeypatch):
    from ipm.proposals import data as D

    monkeypatch.setattr(D, "render_sample", lambda *a, **k: None)
    with pytest.raises(InputError, match=r"expected renders of its samples in the image, got 0 of 1050 tries"):
        D.make_samples(get_generator("dishes"), 1, seed=0)


def test_proposal_settings_that_cannot_apply_are_refused_before_a_run_folder(tmp_path, capsys):
    masks = tmp_path / "m"
    code, _, err = run_cli(["render", "dishes", "--preset", "mug", "--views", "1", "--size", "48", "--no-previews",
                            "-o", str(masks)], capsys)
    assert code == 0, err
    (tmp_path / "text.npz").write_text("weights\n")
    cases = [(["--proposals", str(tmp_path / "text.npz"), "--init", "learned"], "text.npz"),
             (["--proposals", str(tmp_path / "text.npz")], "proposals: applies with init learned or both"),
             (["--proposals", str(tmp_path / "none.npz"), "--init", "both"], "none.npz")]
    for extra, message in cases:
        code, _, err = run_cli(["fit", "dishes", "--masks", str(masks), "--budget", "3", *extra,
                                "-o", str(tmp_path / "run")], capsys)
        assert code == 2 and err.count("\n") == 1 and message in err, err
        assert not (tmp_path / "run").exists()


def test_training_settings_out_of_range_are_refused_with_one_line(tmp_path, capsys):
    for extra, message in [(["--workers", "0"], "--workers: expected 1 to 256 processes, got 0"),
                           (["--checkpoint-every", "0"], "--checkpoint-every: expected at least 1"),
                           (["--samples", "0"], "samples: expected an integer from 1")]:
        code, _, err = run_cli(["train-proposals", "dishes", "-o", str(tmp_path / "w.npz"), *extra], capsys)
        assert code == 2 and err.count("\n") == 1 and message in err, err
        assert not list(tmp_path.iterdir())


def test_learned_starts_keep_the_pose_when_it_is_held(tmp_path, capsys):
    """With --no-pose the proposals are evaluated where the start stands: no look rescales or moves them."""
    masks = tmp_path / "m"
    code, _, err = run_cli(["render", "dishes", "--preset", "mug", "--views", "1", "--size", "48", "--no-previews",
                            "-o", str(masks)], capsys)
    assert code == 0, err
    gen = get_generator("dishes")  # a two-step network: unsure of the handle and the spout, so several proposals
    weights = save_weights(train(gen, TrainSettings(samples=24, steps=2, batch=8), data=_tiny(gen)),
                           tmp_path / "w.npz")
    code, _, err = run_cli(["fit", "dishes", "--masks", str(masks), "--init", "learned", "--proposals", str(weights),
                            "--no-pose", "--budget", "30", "-o", str(tmp_path / "run")], capsys)
    assert code == 0, err
    result = json.loads((tmp_path / "run" / "result.json").read_text())
    assert 2 <= len(result["start"]["proposals"]) <= 4
    records = [json.loads(line) for line in (tmp_path / "run" / "trajectory.jsonl").read_text().splitlines()]
    learned = [r for r in records if r["phase"] == "init:learned"]
    assert learned and all(r["x"][-5:] == pytest.approx([0.5] * 5) for r in learned)  # the identity pose


def test_where_a_fit_starts_by_default_is_the_generators():
    """``init`` unset: the building's fits start from the presets and the shipped proposals together, the dishes'
    from the presets; an explicit value wins; a weights file with a generator whose default is the presets is
    refused as with an explicit ``--init presets``."""
    from ipm.optim.fit import check_proposals, init_mode
    from ipm.optim.targets import MaskTarget

    building, dishes = get_generator("building"), get_generator("dishes")
    assert init_mode(building, FitSettings()) == "both" and init_mode(dishes, FitSettings()) == "presets"
    assert init_mode(building, FitSettings(init="presets")) == "presets"
    assert init_mode(dishes, FitSettings(init="learned")) == "learned"
    mask = torch.zeros(1, 8, 8)
    mask[0, 2:6, 3:5] = 1
    target = MaskTarget(mask, [orbit_camera(0.0, 20.0, 3.2, width=8, height=8)])
    assert check_proposals(building, target, FitSettings()) is not None  # the shipped weights
    assert check_proposals(building, target, FitSettings(init="presets")) is None
    with pytest.raises(InputError, match="proposals: applies with init learned or both, got init presets"):
        check_proposals(dishes, target, FitSettings(proposals="w.npz"))


def test_a_generator_default_start_that_is_no_mode_is_refused():
    from ipm.optim.fit import init_mode

    class Odd:
        name, init = "odd", "learn"

    with pytest.raises(InputError, match=r"odd: init: expected one of both, learned, presets as the generator's default"):
        init_mode(Odd(), FitSettings())


_HEADS_DIGEST = """
import hashlib, sys, torch
from ipm.generators import get_generator
from ipm.proposals import load_proposer
from ipm.render.camera import orbit_camera
h = hashlib.sha256()
for g in ("building", "dishes"):
    proposer = load_proposer(get_generator(g), None)
    masks = []
    for i in range(4):
        m = torch.zeros(120, 100)
        m[60 - 10 - 8 * i:60 + 10 + 8 * i, 20 + 3 * i:80 - 2 * i] = 1
        masks.append(m)
        out = proposer.heads(m)
        for t in [out["mean"], out["log_std"], *out["discrete"], out["yaw"]]:
            h.update(t.numpy().tobytes())
    cams = [orbit_camera(30.0 + 97.0 * k, 25.0, 3.2, width=100, height=120) for k in range(4)]
    for k in (1, 2, 4):
        for p in proposer.propose_views(torch.stack(masks[:k]), cams[:k]):
            h.update(repr((p.values, p.probability, p.yaw_deg, p.std)).encode())
print(h.hexdigest())
"""


def test_proposals_are_the_same_bits_whatever_cpu_kernels_torch_picks():
    """torch picks its CPU kernels at run time; ``ATEN_CPU_CAPABILITY=default`` forces the plain ones another CPU
    would run. The shipped networks' outputs (float64 inference rounded to float32) and the proposals made of them,
    from one view and fused from several (their probabilities rounded to float32 too), come out bit for bit the same
    under both, and with two threads: a fit that starts from them starts in the same place on every machine."""
    import os
    import subprocess
    import sys

    digests = set()
    for env in ({}, {"ATEN_CPU_CAPABILITY": "default"}, {"IPM_THREADS": "2", "OMP_NUM_THREADS": "2"}):
        code = _HEADS_DIGEST if "IPM_THREADS" not in env else "import torch; torch.set_num_threads(2)\n" + _HEADS_DIGEST
        proc = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=300,
                              env={**os.environ, **env})
        assert proc.returncode == 0, proc.stderr
        digests.add(proc.stdout.strip())
    assert len(digests) == 1, digests


def _outputs(mean, std, discrete, yaw) -> dict:
    """Network outputs of one view (batch of one), as :meth:`ipm.proposals.Proposer.heads` gives them."""
    t = lambda v: torch.tensor([v], dtype=torch.float32)  # noqa: E731
    return {"mean": t(mean), "log_std": t([math.log(s) for s in std]),
            "discrete": [t([math.log(p) for p in head]) for head in discrete], "yaw": t(yaw)}


def test_views_are_fused_as_independent_evidence_of_one_object():
    """Each discrete head's probabilities multiply over the views (a handle one view hides at 0.3 and another
    shows at 0.9 comes out at 0.79), continuous means are weighted by their precisions, and the yaw is the peak of
    the product of the views' yaw distributions turned into the world: of two views unsure between a yaw and its
    half turn, the surer one decides, though the other alone would pick the half turn."""
    from ipm.proposals.net import YAW_BINS
    from ipm.proposals.propose import fuse

    step = 360.0 / YAW_BINS
    yaw_a = [-9.0] * YAW_BINS
    yaw_a[4], yaw_a[4 + YAW_BINS // 2] = 0.0, -0.5   # world 60 (bin 4 of a camera at TRAIN_AZIMUTH) or 240
    yaw_b = [-9.0] * YAW_BINS
    yaw_b[4 - 6], yaw_b[4 - 6 + YAW_BINS // 2] = -0.05, 0.0   # a camera 90 degrees on: 60 is its bin -2, 240 its 10
    cam_a, cam_b = orbit_camera(TRAIN_AZIMUTH, 25.0, 3.2), orbit_camera(TRAIN_AZIMUTH + 90.0, 25.0, 3.2)
    assert 6 * step == pytest.approx(90.0)
    a = _outputs([0.2, 0.5], [0.1, 0.2], [[0.7, 0.3]], yaw_a)
    b = _outputs([0.6, 0.5], [0.2, 0.2], [[0.1, 0.9]], yaw_b)
    mean, std, probs, yaw = fuse([(a, cam_a), (b, cam_b)])
    assert mean.tolist() == pytest.approx([(0.2 / 0.01 + 0.6 / 0.04) / (1 / 0.01 + 1 / 0.04), 0.5], abs=1e-6)
    assert std.tolist() == pytest.approx([(1 / 0.01 + 1 / 0.04) ** -0.5, 0.2 / math.sqrt(2)], abs=1e-6)
    assert probs[0].tolist() == pytest.approx([0.07 / 0.34, 0.27 / 0.34], abs=1e-6)
    assert yaw == pytest.approx(60.0, abs=0.5)
    # alone, each view picks its own peak: the first 60, the second 240
    from ipm.proposals.propose import summary

    assert summary(a, cam_a)[3] % 360.0 == pytest.approx(60.0, abs=0.5)
    assert summary(b, cam_b)[3] % 360.0 == pytest.approx(240.0, abs=0.5)


def test_a_cameras_turn_moves_the_yaw_bins_between_bins_linearly():
    from ipm.proposals.net import YAW_BINS
    from ipm.proposals.propose import world_bins

    step = 360.0 / YAW_BINS
    logits = torch.randn(YAW_BINS, generator=torch.Generator().manual_seed(0)).tolist()
    out = _outputs([0.5], [0.1], [], logits)
    p = torch.softmax(torch.tensor(logits, dtype=torch.float32).double(), 0)
    same = world_bins(out, orbit_camera(TRAIN_AZIMUTH, 25.0, 3.2))
    assert torch.allclose(same, p, atol=1e-12)
    one_bin = world_bins(out, orbit_camera(TRAIN_AZIMUTH + step, 25.0, 3.2))
    assert torch.allclose(one_bin, torch.roll(p, 1), atol=1e-9)   # world bin j holds the camera's bin j - 1
    half = world_bins(out, orbit_camera(TRAIN_AZIMUTH + step / 2, 25.0, 3.2))
    assert torch.allclose(half, 0.5 * (p + torch.roll(p, 1)), atol=1e-9)
    assert float(half.sum()) == pytest.approx(1.0)


def test_one_view_is_proposed_as_before_and_more_views_sharpen_the_shipped_networks_guess():
    """``propose_views`` with one view is ``propose``; the building's network shown the same box from two cameras
    a quarter turn apart gives one answer with the discrete heads surer than either view's alone."""
    proposer = load_proposer(get_generator("building"), None)
    m = torch.zeros(120, 100)
    m[30:90, 20:80] = 1
    cams = [orbit_camera(TRAIN_AZIMUTH + 90.0 * k, 25.0, 3.2, width=100, height=120) for k in range(2)]
    assert proposer.propose_views(m[None], cams[:1]) == proposer.propose(m, cams[0])
    with pytest.raises(ValueError, match="propose_views: expected one camera per mask, got 2 masks and 1 cameras"):
        proposer.propose_views(torch.stack([m, m]), cams[:1])
    two = proposer.propose_views(torch.stack([m, m]), cams)
    one = [proposer.propose(m, c)[0] for c in cams]
    assert 1 <= len(two) <= 4
    assert two[0].probability > max(p.probability for p in one)
    assert -180.0 <= two[0].yaw_deg < 180.0


def test_a_fit_from_several_views_starts_from_all_of_their_proposals():
    """The fit's proposals (``learned_proposals``) are those of every view fused, not the first view's."""
    from ipm.optim.fit import learned_proposals
    from ipm.optim.targets import MaskTarget

    gen = get_generator("building")
    proposer = load_proposer(gen, None)
    masks = torch.zeros(2, 120, 100)
    masks[0, 30:90, 20:80] = 1
    masks[1, 40:90, 35:65] = 1
    cams = [orbit_camera(TRAIN_AZIMUTH + 90.0 * k, 25.0, 3.2, width=100, height=120) for k in range(2)]
    got = learned_proposals(gen, MaskTarget(masks, cams), FitSettings())
    assert got == proposer.propose_views(masks, cams)
    assert got != proposer.propose(masks[0], cams[0])
