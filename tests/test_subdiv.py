"""Issue #14, linear subdivision (ipm.subdiv): Loop and midpoint as sparse operators against libigl's own
subdivided meshes, their gradients (gradcheck, torch.func), the Jacobian of a subdivided generator mesh
(S J), and the checks of bad meshes and levels, in the API and the CLI."""

from __future__ import annotations

import igl
import numpy as np
import pytest
import torch
import trimesh
from torch.func import jacfwd, jacrev, vmap

from ipm.errors import InputError
from ipm.generators import get_generator
from ipm.jacobian import mesh_fd_jacobian
from ipm.subdiv import SCHEMES, subdivide
from tests.conftest import run_cli

REFERENCE = {"loop": igl.loop, "midpoint": igl.upsample}


def _sphere(level: int = 1) -> tuple[np.ndarray, np.ndarray]:
    m = trimesh.creation.icosphere(level)
    return np.asarray(m.vertices, dtype=np.float64), np.asarray(m.faces, dtype=np.int64)


def _open_cap() -> tuple[np.ndarray, np.ndarray]:
    """The lower part of a sphere: a mesh with one boundary loop."""
    V, F = _sphere(2)
    m = trimesh.Trimesh(V, F[V[F].mean(1)[:, 2] < 0.3], process=False)
    m.remove_unreferenced_vertices()
    return np.asarray(m.vertices, dtype=np.float64), np.asarray(m.faces, dtype=np.int64)


@pytest.mark.parametrize("scheme", ["loop", "midpoint"])
@pytest.mark.parametrize("mesh", ["closed", "boundary"])
@pytest.mark.parametrize("levels", [1, 2])
def test_the_operator_gives_libigls_subdivided_mesh(scheme, mesh, levels):
    V, F = _sphere() if mesh == "closed" else _open_cap()
    NV, NF = subdivide(torch.as_tensor(V), F, scheme, levels)
    RV, RF = REFERENCE[scheme](V, F, levels)
    assert np.array_equal(NF, RF)
    assert np.abs(NV.numpy() - RV).max() < 1e-12


def test_loop_rules_on_a_closed_mesh_by_hand():
    # an edge vertex is 3/8 of each end and 1/8 of the two opposite corners; an old vertex of valence n
    # keeps 1 - n beta of itself (Warren's beta 3/16 for n = 3, else 3 / (8 n))
    V, F = _sphere(0)    # the icosahedron: valence 5
    NV, NF = subdivide(torch.as_tensor(V), F, "loop", 1)
    neighbours = {j for f in F if 0 in f for j in f if j != 0}
    beta = 3 / (8 * 5)
    want0 = (1 - 5 * beta) * V[0] + beta * V[sorted(neighbours)].sum(0)
    assert np.abs(NV[0].numpy() - want0).max() < 1e-12
    a, b = F[0][0], F[0][1]
    opposite = [f[[i for i in range(3) if f[i] not in (a, b)][0]] for f in F if a in f and b in f]
    want_edge = 3 / 8 * (V[a] + V[b]) + 1 / 8 * (V[opposite[0]] + V[opposite[1]])
    assert np.abs(NV.numpy() - want_edge).sum(1).min() < 1e-12


@pytest.mark.parametrize("scheme", ["loop", "midpoint"])
def test_gradients_are_the_transposed_operator(scheme):
    V, F = _open_cap()
    x = torch.as_tensor(V).requires_grad_()
    assert torch.autograd.gradcheck(lambda v: subdivide(v, F, scheme, 2)[0], (x,))
    assert torch.autograd.gradgradcheck(lambda v: subdivide(v, F, scheme, 1)[0].pow(2).sum(1), (x,))


def test_torch_func_transforms_pass_through():
    V, F = _sphere(1)

    def f(v):
        return subdivide(v, F, "loop", 1)[0]

    x = torch.as_tensor(V)
    assert torch.equal(jacfwd(f)(x), jacrev(f)(x))
    batch = torch.randn(4, *x.shape, dtype=torch.float64)
    assert torch.allclose(vmap(f)(batch), torch.stack([f(b) for b in batch]), atol=1e-14)


def test_float32_and_the_input_device_are_followed():
    V, F = _sphere(1)
    out, _ = subdivide(torch.as_tensor(V, dtype=torch.float32), F, "loop", 1)
    assert out.dtype == torch.float32 and out.device.type == "cpu"


def test_the_jacobian_of_a_subdivided_dishes_mesh_is_S_J():
    g = get_generator("dishes")
    theta, d = g.split(g.values("mug"), torch.float64)
    faces = g.mesh(theta, d).faces.numpy()
    op, _ = SCHEMES.get("loop").operator(faces, g.mesh(theta, d).n_verts, 1)

    def coarse(t):
        return g.mesh(t, d).verts

    def fine(t):
        return subdivide(coarse(t), faces, "loop", 1)[0].reshape(-1)

    J = jacfwd(lambda t: coarse(t).reshape(-1))(theta)
    SJ = torch.as_tensor(op.scipy @ J.reshape(J.shape[0] // 3, -1).numpy()).reshape(-1, J.shape[1])
    J_fine = jacfwd(fine)(theta)
    assert (J_fine - SJ).abs().max() < 1e-10
    # and both against float64 central differences of the subdivided mesh
    fd = mesh_fd_jacobian(lambda t: fine(t).reshape(-1, 3), theta)
    assert ((J_fine - fd).abs() / fd.abs().clamp(min=1)).max() < 1e-6


@pytest.mark.parametrize("faces, n, message", [
    (np.zeros((0, 3), dtype=np.int64), 3, "empty mesh"),
    (np.array([[0, 1, 5]]), 3, "face indices must lie in [0, 2]"),
    (np.array([[0, 1, 1]]), 2, "repeats a vertex"),
    (np.array([[0, 1, 2]]), 4, "1 vertex(es) on no face"),
    (np.array([[0, 1, 2], [1, 0, 3], [0, 1, 4]]), 5, "shared by more than two faces (non-manifold)"),
    (np.array([[0, 1, 2], [0, 1, 3]]), 4, "disagree on orientation"),
    (np.array([[0, 1]]), 2, "expected triangle faces"),
])
def test_bad_meshes_are_refused_with_one_line(faces, n, message):
    with pytest.raises(InputError, match=message.replace("[", r"\[").replace("(", r"\(").replace(")", r"\)")):
        subdivide(torch.zeros(n, 3, dtype=torch.float64), faces, "loop", 1)


@pytest.mark.parametrize("levels", [0, 7, True, 1.5])
def test_levels_out_of_range_are_refused(levels):
    V, F = _sphere(0)
    with pytest.raises(InputError, match="levels: expected an integer from 1 to 6"):
        subdivide(torch.as_tensor(V), F, "loop", levels)


def test_an_output_too_large_is_refused_before_any_work():
    V, F = _sphere(5)    # 10242 vertices: 6 levels would make 41.9 million
    with pytest.raises(InputError, match="6 levels of a mesh with 10242 vertices would make 41943042 vertices"):
        SCHEMES.get("loop").operator(F, len(V), 6)


def test_cli_subdivides_an_stl_after_welding(tmp_path, capsys):
    V, F = _sphere(1)
    soup = trimesh.Trimesh(V[F].reshape(-1, 3), np.arange(3 * len(F)).reshape(-1, 3), process=False)
    src = tmp_path / "soup.stl"
    soup.export(src)
    out = tmp_path / "fine.ply"
    code, stdout, err = run_cli(["subdivide", src, "--levels", "2", "-o", out, "--json"], capsys)
    assert code == 0, err
    import json

    info = json.loads(stdout)
    assert info["input"]["welded"] == len(V) and info["faces"] == 16 * len(F)
    got = trimesh.load_mesh(out, process=False)
    RV, _ = igl.loop(V, F, 2)
    # the same surface as libigl's (vertex order follows the weld, so compare as point sets)
    d = np.linalg.norm(np.sort(np.round(np.asarray(got.vertices), 6), axis=0) - np.sort(np.round(RV, 6), axis=0))
    assert d < 1e-4


@pytest.mark.parametrize("args, message", [
    (["--levels", "0"], "--levels: expected an integer from 1 to 6, got 0"),
    (["--levels", "7"], "--levels: expected an integer from 1 to 6, got 7"),
    (["--method", "butterfly"], "--method: expected one of loop, midpoint, neural, got 'butterfly'"),
])
def test_cli_bad_options_exit_2_with_one_line(tmp_path, capsys, args, message):
    V, F = _sphere(0)
    src = tmp_path / "ico.ply"
    trimesh.Trimesh(V, F, process=False).export(src)
    out = tmp_path / "out.ply"
    code, _, err = run_cli(["subdivide", src, "-o", out, *args], capsys)
    assert code == 2 and message in err and len(err.strip().splitlines()) == 1
    assert not out.exists()


def test_cli_non_manifold_mesh_exits_2_and_writes_nothing(tmp_path, capsys):
    V = np.array([[0, 0, 0], [1, 0, 0], [0, 1, 0], [0, -1, 0], [0, 0, 1]], dtype=float)
    F = np.array([[0, 1, 2], [1, 0, 3], [0, 1, 4]])
    src = tmp_path / "fin.ply"
    trimesh.Trimesh(V, F, process=False).export(src)
    out = tmp_path / "out.obj"
    code, _, err = run_cli(["subdivide", src, "-o", out], capsys)
    assert code == 2 and "non-manifold" in err and len(err.strip().splitlines()) == 1
    assert not out.exists()


def test_cli_jacobian_of_a_subdivided_mesh(tmp_path, capsys):
    out = tmp_path / "J.npz"
    code, stdout, err = run_cli(["jacobian", "dishes", "--preset", "mug", "--subdivide", "midpoint",
                                 "--check", "-o", out], capsys)
    assert code == 0, err
    data = np.load(out)
    g = get_generator("dishes")
    mesh = g.mesh(*g.split(g.values("mug"), torch.float64))
    assert data["J"].shape == (3 * len(data["verts"]), len(g.spec.continuous))
    assert len(data["faces"]) == 4 * mesh.n_faces and "check: ok" in stdout


def test_cli_jacobian_refuses_a_scheme_that_is_not_linear(tmp_path, capsys):
    out = tmp_path / "J.npz"
    code, _, err = run_cli(["jacobian", "dishes", "--subdivide", "neural", "-o", out], capsys)
    assert code == 2 and "neural is not a linear scheme" in err and not out.exists()
