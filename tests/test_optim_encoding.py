"""The search vector's layout (ipm.optim.encoding): round trips between named dicts, vectors and normalized
vectors for real generators' specs, and normalized vectors that stay in [0, 1] (property tests)."""

from __future__ import annotations

import math

import numpy as np
import pytest
import torch
from hypothesis import given, settings
from hypothesis import strategies as st

from ipm.generators import get_generator
from ipm.optim import encoding as E

GENERATORS = ["dishes", "building", "mug"]
SPECS = {name: get_generator(name).spec for name in GENERATORS}
finite = st.floats(allow_nan=False, allow_infinity=False, min_value=-1e6, max_value=1e6)


@st.composite
def named_values(draw, spec):
    """An in-range named dict of ``spec``."""
    out = {}
    for p in spec.params:
        if p.continuous:
            out[p.name] = draw(st.floats(float(p.lo), float(p.hi), allow_nan=False))
        else:
            out[p.name] = draw(st.integers(int(p.lo), int(p.hi)))
    return out


@st.composite
def pose(draw):
    t = [draw(st.floats(-E.T_RANGE, E.T_RANGE)) for _ in range(3)]
    yaw = draw(st.floats(-180.0, 180.0, exclude_max=True))
    scale = 2.0 ** draw(st.floats(-E.LOG2S_RANGE, E.LOG2S_RANGE))
    camera = (draw(st.floats(*E.ELEV)), draw(st.floats(*E.DIST)), draw(st.floats(*E.FOV)))
    return t, yaw, scale, camera


def _close(a: float, b: float, span: float = 1.0) -> bool:
    return abs(a - b) <= 1e-9 * max(1.0, span)


@pytest.mark.parametrize("name", GENERATORS)
@settings(max_examples=40, deadline=None)
@given(data=st.data())
def test_named_dict_vector_normalized_and_back(name, data):
    spec = SPECS[name]
    values = data.draw(named_values(spec))
    t, yaw, scale, camera = data.draw(pose())
    with_camera = data.draw(st.booleans())
    layout = E.Layout.from_spec(spec, camera=with_camera)
    theta, discrete = E.to_vectors(spec, values)
    x = E.encode(layout, theta, t=t, yaw=yaw, scale=scale, camera=camera)
    assert x.dtype == torch.float64 and x.shape == (layout.m,)
    assert bool(((x >= 0) & (x <= 1)).all())
    # theta0 of other values: every coordinate is free, so none of it may leak through
    theta_back, t_back, yaw_back, scale_back, cam_back = E.decode(layout, x, spec.lower())
    back = E.from_vectors(spec, theta_back, discrete)
    for p in spec.params:
        if p.continuous:
            assert _close(back[p.name], values[p.name], float(p.hi - p.lo)), (p.name, back[p.name], values[p.name])
        else:
            assert back[p.name] == values[p.name] and isinstance(back[p.name], int)
    assert all(_close(float(a), b, E.T_RANGE) for a, b in zip(t_back, t))
    # yaws are angles: -180 and 180 are the same
    assert _close((float(yaw_back) - yaw + 180.0) % 360.0 - 180.0, 0.0, 360.0) and _close(float(scale_back), scale, 4.0)
    assert (cam_back is None) == (not with_camera)
    if with_camera:
        assert all(_close(float(a), b, 100.0) for a, b in zip(cam_back, camera))


@pytest.mark.parametrize("name", GENERATORS)
@settings(max_examples=40, deadline=None)
@given(data=st.data())
def test_only_free_coordinates_move(name, data):
    spec = SPECS[name]
    cont = [p.name for p in spec.continuous]
    free = data.draw(st.lists(st.sampled_from(cont), unique=True, max_size=len(cont)))
    layout = E.Layout.from_spec(spec, free)
    theta0, _ = E.to_vectors(spec, data.draw(named_values(spec)))
    theta, _ = E.to_vectors(spec, data.draw(named_values(spec)))
    u = E.normalize(layout, theta)
    assert u.shape == (len(free),) and bool(((u >= 0) & (u <= 1)).all())
    out = E.denormalize(layout, u, theta0)
    for i, n in enumerate(cont):
        if n in free:
            assert _close(float(out[i]), float(theta[i]), float(layout.hi[i] - layout.lo[i]))
        else:
            assert float(out[i]) == float(theta0[i])  # held coordinates are copied, bit for bit


@pytest.mark.parametrize("name", GENERATORS)
@settings(max_examples=40, deadline=None)
@given(data=st.data())
def test_discrete_genes_round_trip_exactly(name, data):
    spec = SPECS[name]
    params = list(spec.discrete)
    values = data.draw(named_values(spec))
    _, discrete = E.to_vectors(spec, values)
    z = E.encode_discrete(params, discrete)
    assert z.shape == (len(params),) and bool(((z >= 0) & (z <= 1)).all())
    assert E.decode_discrete(params, z) == discrete
    # any genes in [0, 1] decode to in-range values
    genes = np.array(data.draw(st.lists(st.floats(0, 1), min_size=len(params), max_size=len(params))))
    for p, v in zip(params, E.decode_discrete(params, genes).values()):
        assert p.lo <= v <= p.hi


@pytest.mark.parametrize("name", GENERATORS)
@settings(max_examples=40, deadline=None)
@given(data=st.data())
def test_normalized_vectors_stay_in_the_box_for_any_input(name, data):
    spec = SPECS[name]
    layout = E.Layout.from_spec(spec, camera=True)
    theta = torch.tensor(data.draw(st.lists(finite, min_size=spec.n_continuous, max_size=spec.n_continuous)),
                         dtype=torch.float64)
    t = data.draw(st.lists(finite, min_size=3, max_size=3))
    yaw = data.draw(finite)
    scale = data.draw(st.floats(1e-6, 1e6))
    camera = tuple(data.draw(st.lists(finite, min_size=3, max_size=3)))
    x = E.encode(layout, theta, t=t, yaw=yaw, scale=scale, camera=camera)
    assert bool(torch.isfinite(x).all()) and bool(((x >= 0) & (x <= 1)).all())


@settings(max_examples=60, deadline=None)
@given(yaw=st.floats(-1e4, 1e4))
def test_yaw_is_wrapped_to_half_a_turn_either_way(yaw):
    p = E.encode_pose(yaw=yaw)
    _, back, _ = E.decode_pose(p)
    assert -180.0 - 1e-9 <= float(back) < 180.0 + 1e-9
    assert math.isclose(math.cos(math.radians(float(back))), math.cos(math.radians(yaw)), abs_tol=1e-6)
