"""Issue #14, neural subdivision: exact procedural pairs, invariance to rigid motion, training that beats
midpoint subdivision on held-out dishes, weights files that cannot run code, checkpoints that resume
exactly, and the CLI."""

from __future__ import annotations

import json

import numpy as np
import pytest
import torch

from ipm.errors import InputError
from ipm.subdiv import SCHEMES, subdivide
from ipm.subdiv.halfflap import flaps, next_level
from ipm.subdiv.neural import NeuralSubdivision, load_weights, save_weights
from ipm.subdiv.pairs import dish_pair, random_dishes
from ipm.subdiv.train import TrainSettings, evaluate, make_pairs, train
from tests.conftest import run_cli


def _rotation(seed: int) -> torch.Tensor:
    q, _ = torch.linalg.qr(torch.as_tensor(np.random.default_rng(seed).normal(size=(3, 3))))
    return q * torch.sign(torch.det(q))


def test_pairs_are_exact_and_nest():
    pair = dish_pair(random_dishes(1, np.random.default_rng(3))[0], 2)
    # level 1 keeps the coarse vertices, level 2 the level-1 ones (the finer bodies hold them exactly;
    # dish_pair itself refuses a coarse vertex more than 1e-9 from its finer twin)
    assert torch.equal(pair.levels[0][: len(pair.verts)], pair.verts)
    assert torch.equal(pair.levels[1][: len(pair.levels[0])], pair.levels[0])
    edges, faces1 = next_level(pair.faces, len(pair.verts))
    assert len(pair.levels[0]) == len(pair.verts) + len(edges) and len(faces1) == 4 * len(pair.faces)
    # an inserted vertex lies near its edge (the generator's surface between the ends), never far away
    mid = 0.5 * (pair.verts[edges[:, 0]] + pair.verts[edges[:, 1]])
    length = (pair.verts[edges[:, 0]] - pair.verts[edges[:, 1]]).norm(dim=1)
    assert ((pair.levels[0][len(pair.verts):] - mid).norm(dim=1) < 0.6 * length).all()


def test_half_flaps_pair_every_directed_edge_with_its_twin():
    pair = dish_pair(random_dishes(1, np.random.default_rng(0))[0], 1)
    fl = flaps(pair.faces, len(pair.verts))
    a, b, c, d = fl.abcd.T
    code = {(int(x), int(y)): int(z) for x, y, z in zip(a, b, c)}
    for x, y, z in zip(a, b, d):   # d is the corner of the triangle on the other side
        assert code[(int(y), int(x))] == int(z)
    assert np.array_equal(np.sort(fl.edges[fl.edge], 1), np.sort(np.stack([a, b], 1), 1))


def test_a_rigidly_moved_input_gives_the_moved_output():
    net = SCHEMES.get("neural").network().double()
    pair = dish_pair(random_dishes(1, np.random.default_rng(5))[0], 1)
    R, t = _rotation(1), torch.tensor([0.3, -1.2, 2.0], dtype=torch.float64)
    with torch.no_grad():
        out, _ = net(pair.verts, pair.faces, 2)
        moved, _ = net(pair.verts @ R.T + t, pair.faces, 2)
        scaled, _ = net(pair.verts * 3.0, pair.faces, 2)
    assert (moved[-1] - (out[-1] @ R.T + t)).abs().max() < 1e-5
    assert (scaled[-1] - 3.0 * out[-1]).abs().max() < 1e-5


def test_a_network_trained_under_a_minute_beats_midpoint_on_held_out_dishes():
    net = train(TrainSettings(pairs=16, steps=500, seed=0))
    scores = evaluate(net, make_pairs(6, 2, seed=1000))
    assert scores["neural"] < 0.85 * scores["midpoint"], scores
    assert scores["neural"] < scores["loop"], scores


def test_the_shipped_weights_beat_midpoint_and_loop_on_held_out_dishes():
    scores = evaluate(SCHEMES.get("neural").network(), make_pairs(8, 2, seed=2000))
    assert scores["neural"] < 0.8 * scores["midpoint"] < 0.8 * scores["loop"], scores


def test_gradients_flow_to_the_input_vertices():
    pair = dish_pair(random_dishes(1, np.random.default_rng(7))[0], 1)
    v = pair.verts.float().requires_grad_()
    out, faces = subdivide(v, pair.faces, "neural", 1)
    assert out.dtype == torch.float32 and len(faces) == 4 * len(pair.faces)
    out.pow(2).sum().backward()
    assert torch.isfinite(v.grad).all() and v.grad.abs().sum() > 0


def test_a_checkpoint_resumes_exactly(tmp_path):
    s = TrainSettings(pairs=3, steps=12, seed=4)
    straight = train(s)
    ckpt = tmp_path / "run.ckpt.npz"
    train(TrainSettings(pairs=3, steps=12, seed=4), checkpoint=ckpt, every=5)   # ends at step 12
    # a run stopped at step 5: rewrite the checkpoint as it was, then resume
    part = tmp_path / "part.ckpt.npz"

    class Stop(Exception):
        pass

    def stop_at_6(i, _loss):
        if i == 6:
            raise Stop

    with pytest.raises(Stop):
        train(s, checkpoint=part, every=5, progress=stop_at_6)
    resumed = train(s, checkpoint=part, every=5, resume=True)
    for a, b in zip(straight.state_dict().values(), resumed.state_dict().values()):
        assert torch.equal(a, b)
    with pytest.raises(InputError, match="other settings .*steps"):
        train(TrainSettings(pairs=3, steps=13, seed=4), checkpoint=part, resume=True)


def test_weights_round_trip_and_bad_files_are_refused(tmp_path):
    torch.manual_seed(0)
    net = NeuralSubdivision()
    path = save_weights(net, tmp_path / "w.npz")
    back, _ = load_weights(path)
    for a, b in zip(net.state_dict().values(), back.state_dict().values()):
        assert torch.equal(a, b)
    arrays = dict(np.load(path, allow_pickle=False))
    # a pickled object (which would run code when unpickled) is refused, not loaded
    pickled = tmp_path / "pickled.npz"
    np.savez(pickled, **{**arrays, "net.init_net.0.weight": np.array([object()], dtype=object)})
    with pytest.raises(InputError, match="expected an .npz of plain arrays"):
        load_weights(pickled)
    wrong = tmp_path / "wrong.npz"
    np.savez(wrong, **{**arrays, "net.edge_net.4.bias": np.zeros(5, dtype=np.float32)})
    with pytest.raises(InputError, match=r"parameter edge_net.4.bias: expected a float array of shape \(19,\)"):
        load_weights(wrong)
    no_cfg = tmp_path / "nocfg.npz"
    np.savez(no_cfg, **{k: v for k, v in arrays.items() if k != "config"})
    with pytest.raises(InputError, match="config entry"):
        load_weights(no_cfg)
    not_zip = tmp_path / "text.npz"
    not_zip.write_text("hello")
    with pytest.raises(InputError, match="plain arrays"):
        load_weights(not_zip)


def test_cli_neural_subdivision_and_bad_weights(tmp_path, capsys):
    import trimesh

    src = tmp_path / "ico.ply"
    trimesh.creation.icosphere(1).export(src)
    out = tmp_path / "fine.obj"
    code, stdout, err = run_cli(["subdivide", src, "--method", "neural", "--levels", "2", "-o", out, "--json"],
                                capsys)
    assert code == 0, err
    assert json.loads(stdout)["faces"] == 16 * 80
    v = np.asarray(trimesh.load_mesh(out, process=False).vertices)
    assert np.isfinite(v).all() and 0.8 < np.linalg.norm(v, axis=1).mean() < 1.2
    bad = tmp_path / "bad.npz"
    np.savez(bad, config=np.array('{"features": 16, "hidden": 64}'))
    out2 = tmp_path / "x.obj"
    code, _, err = run_cli(["subdivide", src, "--method", "neural", "--weights", bad, "-o", out2], capsys)
    assert code == 2 and "parameter" in err and "is missing" in err and len(err.strip().splitlines()) == 1
    assert not out2.exists()
    code, _, err = run_cli(["subdivide", src, "--method", "loop", "--weights", bad, "-o", out2], capsys)
    assert code == 2 and "--weights applies to --method neural" in err
    # a mesh with a boundary: neural subdivision needs twins for every edge
    half = tmp_path / "half.ply"
    m = trimesh.creation.icosphere(1)
    trimesh.Trimesh(m.vertices, m.faces[m.triangles_center[:, 2] > 0], process=False).export(half)
    code, _, err = run_cli(["subdivide", half, "--method", "neural", "-o", out2], capsys)
    assert code == 2 and "boundary edge(s); neural subdivision expects a closed mesh" in err


def test_cli_train_subdivision(tmp_path, capsys):
    out = tmp_path / "w.npz"
    code, stdout, err = run_cli(["train-subdivision", "-o", out, "--pairs", "2", "--steps", "6",
                                 "--checkpoint-every", "2", "--json"], capsys)
    assert code == 0, err
    info = json.loads(stdout)
    assert set(info["held_out_distance"]) == {"neural", "midpoint", "loop"}
    assert out.exists() and not out.with_suffix(".ckpt.npz").exists()
    load_weights(out)
    code, _, err = run_cli(["train-subdivision", "-o", tmp_path / "v.npz", "--resume"], capsys)
    assert code == 2 and "resume: expected an existing checkpoint" in err
    code, _, err = run_cli(["train-subdivision", "-o", tmp_path / "v.npz", "--levels", "4"], capsys)
    assert code == 2 and "--levels: expected an integer from 1 to 3, got 4" in err
