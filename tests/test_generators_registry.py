"""Every registered mesh generator and preset, automatically: watertight positive-volume output,
topology fixed by the discrete values, and Jacobians equal to float64 central differences."""

from __future__ import annotations

import pytest
import torch

from ipm.generators import all_generators, get_generator
from ipm.jacobian import check_mesh_jacobian

MESH_GENS = sorted(n for n, f in all_generators().items() if f().kind == "mesh")
CASES = [(g, p) for g in MESH_GENS for p in sorted(get_generator(g).presets)]


@pytest.mark.parametrize("gen, preset", CASES)
def test_presets_are_closed_solids(gen, preset):
    g = get_generator(gen)
    th, d = g.split(g.values(preset))
    m = g.mesh(th, d)
    tm = m.to_trimesh()
    assert tm.is_watertight and tm.volume > 0, (gen, preset)
    # continuous values move vertices only: the faces stay the same
    m2 = g.mesh(g.spec.denormalize(0.3 + 0.4 * torch.rand(th.shape, dtype=torch.float64)), d)
    assert torch.equal(m.faces, m2.faces)


@pytest.mark.parametrize("gen", MESH_GENS)
def test_jacobian_matches_central_differences(gen):
    g = get_generator(gen)
    preset = sorted(g.presets)[0]
    th, d = g.split(g.values(preset))
    chk = check_mesh_jacobian(lambda t: g.mesh(t, d).verts, th)
    assert chk.max_rel_error <= 1e-6, (gen, chk)


def test_generator_files_are_read_by_the_generator_they_declare(tmp_path):
    import json

    from ipm.generators.meshtree import MeshTreeGenerator, mesh_tree_to_json

    snowman = get_generator("snowman")  # a mesh tree preset by name
    assert isinstance(snowman, MeshTreeGenerator)
    path = tmp_path / "snowman.json"
    path.write_text(json.dumps(mesh_tree_to_json(snowman.tree)))
    g = get_generator(str(path))
    assert isinstance(g, MeshTreeGenerator) and g.spec.names == snowman.spec.names
    th, d = g.split(g.values())
    assert torch.equal(g.mesh(th, d).verts, snowman.mesh(th, d).verts)
    # an SDF tree file without the field is still an SDF tree
    assert get_generator("chair").kind == "sdf"
    bad = tmp_path / "odd.json"
    bad.write_text(json.dumps({"generator": "dishes", "params": {}}))
    with pytest.raises(ValueError, match=r"declares generator 'dishes', which has no file format"):
        get_generator(str(bad))


def test_cli_jacobian_uses_the_structured_jacobian_and_checks_it(tmp_path, capsys):
    import json

    import numpy as np

    from ipm.cli import main

    out = tmp_path / "J.npz"
    with pytest.raises(SystemExit) as exit_:
        main(["jacobian", "dishes", "--preset", "mug", "--lod", "low", "--check", "-o", str(out), "--json"])
    code = exit_.value.code
    res = json.loads(capsys.readouterr().out)
    assert code == 0 and res["method"] == "structured" and res["check"] == "ok"
    g = get_generator("dishes")
    th, d = g.split(g.values("mug"))
    J = np.load(out)["J"]
    assert np.allclose(J, g.jacobian(th, d, "low").numpy()) and J.shape == tuple(res["shape"])
