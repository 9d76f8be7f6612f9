import json
import math

import numpy as np
import pytest
import torch

from ipm.params import Param, ParamSpec, load_param_file, param_file_json, parse_assignment

SPEC = ParamSpec((
    Param("height", 1.0, 0.1, 3.0),
    Param("floors", 5, 1, 30, "int"),
    Param("radius", 0.5, 0.0, 2.0),
    Param("has_handle", 1, 0, 1, "bool"),
))


def test_vector_roundtrip():
    vals = SPEC.validate({"height": 2.0, "floors": 7})
    theta = SPEC.to_vector(vals)
    assert theta.tolist() == [2.0, 0.5]
    back = SPEC.from_vector(theta, SPEC.discrete_values(vals))
    assert back == {"height": 2.0, "floors": 7, "radius": 0.5, "has_handle": 1}


def test_normalize_roundtrip_and_range():
    theta = torch.tensor([0.1, 2.0], dtype=torch.float64)
    u = SPEC.normalize(theta)
    assert torch.allclose(u, torch.tensor([0.0, 1.0], dtype=torch.float64))
    assert torch.allclose(SPEC.denormalize(u), theta)


def test_random_within_bounds(rng):
    for _ in range(100):
        v = SPEC.random(rng)
        SPEC.validate(v)
        assert isinstance(v["floors"], int)


@pytest.mark.parametrize("values, message", [
    ({"nope": 1.0}, "unknown parameter 'nope'; valid names: height, floors, radius, has_handle"),
    ({"height": 5.0}, "parameter 'height': expected a value in [0.1, 3.0], got 5.0"),
    ({"floors": 2.5}, "parameter 'floors' is int: expected a whole number in [1, 30], got 2.5"),
    ({"height": float("nan")}, "parameter 'height': expected a finite number, got nan"),
    ({"height": "tall"}, "parameter 'height': expected a number, got 'tall'"),
    ({"has_handle": 2}, "parameter 'has_handle': expected a value in [0, 1], got 2"),
])
def test_validation_messages(values, message):
    with pytest.raises(ValueError) as e:
        SPEC.validate(values)
    assert str(e.value) == message


def test_bad_declarations():
    with pytest.raises(ValueError, match="duplicate parameter name"):
        ParamSpec((Param("a", 0, 0, 1), Param("a", 0, 0, 1)))
    with pytest.raises(ValueError, match="outside"):
        Param("a", 2.0, 0.0, 1.0)


def test_param_file_roundtrip(tmp_path):
    path = tmp_path / "p.json"
    path.write_text(param_file_json("dishes", {"height": 1.5, "floors": 3}))
    gen, raw = load_param_file(path)
    assert gen == "dishes" and raw == {"height": 1.5, "floors": 3}


def test_param_file_errors(tmp_path):
    with pytest.raises(ValueError, match="not found"):
        load_param_file(tmp_path / "missing.json")
    bad = tmp_path / "bad.json"
    bad.write_text("{not json")
    with pytest.raises(ValueError, match="not valid JSON"):
        load_param_file(bad)
    bad.write_text(json.dumps({"params": [1, 2]}))
    with pytest.raises(ValueError, match="'params' object"):
        load_param_file(bad)


def test_parse_assignment():
    assert parse_assignment("height=1.5") == ("height", 1.5)
    with pytest.raises(ValueError, match="NAME=VALUE"):
        parse_assignment("height")
    with pytest.raises(ValueError, match="number"):
        parse_assignment("height=abc")
    name, value = parse_assignment("x=nan")
    assert math.isnan(value)  # rejected later by validate(), with the parameter's name
    assert np.isfinite(parse_assignment("x=-1e-3")[1])
