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
