"""FitSettings and its nested settings: every field refuses bad values with one line naming it."""

import dataclasses
import json
import math

import numpy as np
import pytest

from ipm import losses as L
from ipm.errors import InputError
from ipm.optim.settings import FitSettings
from ipm.optim.strategies.memetic import MemeticSettings
from ipm.optim.strategies.nlopt_global import NloptSettings

NAN, INF = math.nan, math.inf

# field -> (how messages name it, bad values); nested fields as "memetic.population"
BAD = {
    "budget": ("budget", [0, -3, 2.5, "10", True, None]),
    "seed": ("seed", [-1, 1.5, "0", False]),
    "discrete": ("discrete search", ["random", 5, None]),
    "camera": ("camera", ["maybe", 1, True]),
    "loss": ("loss", ["l7", 0, "iou+", "iou+iou", "0*iou", "2*sinkhorn+l7", "iou-mse"]),
    "local": ("local optimizer", ["sgd", None]),
    "lr": ("lr", [0.0, -0.1, 1.5, NAN, INF, "fast", True]),
    "sigma": ("sigma", [-1.0, NAN, INF, -INF, "wide", False]),
    "preset": ("preset", [5, ["mug"]]),
    "free": ("free", ["radius", [1], ["a", None], {"a": 1}]),
    "fix": ("fix", [[], "radius=1", 3]),
    "ranges": ("ranges", [[0, 3], "count=0:3"]),
    "pose": ("pose", [1, "yes", None]),
    "prior_weight": ("prior weight", [-0.5, NAN, INF, "none", True]),
    "polish": ("polish", [-0.1, 1.5, NAN, INF, True]),
    "coarse_to_fine": ("coarse_to_fine", [0, "false"]),
    "resolution": ("resolution", [7, 0, 64.0, True, "high"]),
    "sdf_silhouette": ("sdf_silhouette", ["raster", 1, None, True]),
    "ties": ("ties", [1.0, None]),
    "depth_weight": ("depth_weight", [-1.0, NAN, INF, "heavy", True]),
    "parts_weight": ("parts_weight", [-0.5, NAN, None]),
    "image_weight": ("image_weight", [-2.0, INF, False]),
    "part_cost": ("part_cost", [-0.01, INF, NAN, True]),
    "part_ratio": ("part_ratio", [0.0, -0.5, 1.5, INF, NAN, "half", True]),
    "anchor": ("anchor", [-0.01, INF, NAN, "strong", True]),
    "init": ("init", ["sometimes", 1, True]),
    "proposals": ("proposals", [3, True, ["w.npz"]]),
    "subdivide": ("subdivision", ["butterfly", 1, True]),
    "subdivide_levels": ("subdivision levels", [0, 4, 1.5, True, "2"]),
    "search": ("search", ["memetic", 3, [1, 2]]),
    "memetic": ("memetic", ["fast", 3, [1, 2]]),
    "nlopt": ("nlopt", ["GN_ESCH", 0]),
    "memetic.population": ("memetic population", [1, 0, 4.5, True, "8"]),
    "memetic.tournament": ("memetic tournament", [0, 9, 2.0, True]),
    "memetic.p_mutation": ("memetic p_mutation", [-0.1, 1.1, NAN, INF, True, "often"]),
    "memetic.sigma_mutation": ("memetic sigma_mutation", [-0.1, NAN, INF, False]),
    "memetic.refine_steps": ("memetic refine_steps", [0, 1.5, True]),
    "memetic.lr": ("memetic lr", [0.0, 2.0, NAN, -INF, True]),
    "memetic.stall_generations": ("memetic stall_generations", [0, 2.5, False]),
    "memetic.min_diversity": ("memetic min_diversity", [-0.01, NAN, INF, True]),
    "memetic.neighbours": ("memetic neighbours", [1, "yes"]),
    "memetic.refine_elite": ("memetic refine_elite", [0, None]),
    "memetic.halving": ("memetic halving", [1, "no"]),
    "nlopt.algorithm": ("nlopt algorithm", ["GN_NOPE", 1, None]),
    "nlopt.refine_steps": ("nlopt refine_steps", [0, 2.5, True]),
    "nlopt.population": ("nlopt population", [-1, 0.5, True]),
    "transport": ("transport", ["sinkhorn", 3]),
    "transport.blur": ("transport blur", [0.0, -0.1, 1.5, NAN, INF, True, "wide"]),
    "transport.iterations": ("transport iterations", [0, 1001, 2.5, True]),
    "transport.dustbin": ("transport dustbin", [0.0, -1.0, 3.0, NAN, INF, "far"]),
    "transport.projections": ("transport projections", [0, 4097, 1.5, True]),
    "transport.size": ("transport size", [7, 513, 32.5, False]),
}
# taken as given: lod is a generator's own level-of-detail value
UNCHECKED = {"lod"}


def _settings(field: str, value) -> FitSettings:
    strategies = ("memetic", "nlopt")  # their settings are FitSettings.search entries
    if "." in field:
        parent, name = field.split(".")
        if parent in strategies:
            return FitSettings(search={parent: {name: value}})
        return FitSettings(**{parent: {name: value}})
    if field in strategies:
        return FitSettings(search={field: value})
    return FitSettings(**{field: value})


def _cases() -> list:
    return [pytest.param(field, label, v, id=f"{field}={v!r}") for field, (label, values) in BAD.items()
            for v in values]


def test_every_field_has_bad_values():
    names = {f.name for f in dataclasses.fields(FitSettings)} - UNCHECKED
    names |= {"memetic", "nlopt"}  # the strategies' own settings (FitSettings.search)
    names |= {f"memetic.{f.name}" for f in dataclasses.fields(MemeticSettings)}
    names |= {f"nlopt.{f.name}" for f in dataclasses.fields(NloptSettings)}
    names |= {f"transport.{f.name}" for f in dataclasses.fields(L.TransportSettings)}
    assert names == set(BAD)


@pytest.mark.parametrize("field, label, value", _cases())
def test_a_bad_value_is_an_input_error_naming_the_field(field, label, value):
    with pytest.raises(InputError) as e:
        _settings(field, value).check()
    message = str(e.value)
    assert message.startswith(f"{label}: expected "), message
    assert "\n" not in message and message.endswith(f"got {value!r}"), message


@pytest.mark.parametrize("parent, key", [("memetic", "popsize"), ("nlopt", "algorithm_name")])
def test_unknown_nested_keys_are_refused(parent, key):
    with pytest.raises(InputError, match=rf"{parent} settings: unknown setting\(s\) {key}; expected some of"):
        FitSettings(search={parent: {key: 1}})
    with pytest.raises(InputError, match=rf"{parent} settings: unknown setting\(s\) {key}"):
        dataclasses.replace(FitSettings(), search={parent: {key: 1}})
    with pytest.raises(InputError, match=r"search settings: 'nope': expected a search strategy"):
        FitSettings(search={"nope": {}})
    with pytest.raises(InputError, match=r"search settings: 'enumerate' takes no settings"):
        FitSettings(search={"enumerate": {}})


def test_messages_say_what_is_allowed():
    cases = [(dict(budget=0), "budget: expected an integer >= 1, got 0"),
             (dict(seed=True), "seed: expected a seed >= 0, got True"),
             (dict(sigma=INF), "sigma: expected a blur >= 0, got inf"),
             (dict(polish=NAN), "polish: expected a share of the budget in [0, 1], got nan"),
             (dict(camera="maybe"), "camera: expected one of 'fit', 'known', got 'maybe'"),
             (dict(search={"memetic": {"population": 1}}), "memetic population: expected a population >= 2, got 1"),
             (dict(search={"memetic": {"tournament": 9}}),
              "memetic tournament: expected a size in [1, 8] (the population), got 9"),
             (dict(search={"nlopt": {"population": -1}}), "nlopt population: expected a population >= 0, got -1"),
             (dict(free=["a", 1]), "free: expected a list of parameter names, got ['a', 1]")]
    for kw, message in cases:
        with pytest.raises(InputError) as e:
            FitSettings(**kw).check()
        assert str(e.value) == message


@pytest.mark.parametrize("kw", [
    dict(budget=1, seed=0, lr=1.0, sigma=0.0, prior_weight=0.0, polish=0.0, resolution=8),
    dict(lr=1e-9, polish=1.0, sigma=1e9, prior_weight=1e9, resolution=4096, budget=10**9),
    dict(lr=None, preset=None, free=None, fix={}, ranges={}, lod="high"),
    dict(free=["radius", "height"], fix={"radius": 0.5}, ranges={"count": [1, 3]}),
    dict(free=("radius",), sigma=1, prior_weight=2, polish=1),  # a tuple of names, ints for numbers
    dict(budget=np.int64(5), seed=np.int32(3), sigma=np.float32(0.5), polish=np.float64(0.5)),
    dict(camera="fit", discrete="none", loss="mse", local="lbfgs", pose=False, coarse_to_fine=False, ties=False),
    dict(search={"memetic": {"population": 2, "tournament": 2, "p_mutation": 0.0, "sigma_mutation": 0.0,
                             "refine_steps": 1, "lr": 1.0, "stall_generations": 1, "min_diversity": 0.0,
                             "neighbours": False, "refine_elite": False}}),
    dict(search={"memetic": MemeticSettings(p_mutation=1, tournament=8),
                 "nlopt": {"algorithm": "GN_ISRES", "refine_steps": 1, "population": 0}}),
])
def test_valid_edge_values_pass(kw):
    s = FitSettings(**kw)
    s.check()
    again = FitSettings(**json.loads(json.dumps(s.to_json(), default=_json)))
    again.check()
    assert dataclasses.replace(s) == s


def _json(v):
    return v.item() if isinstance(v, np.generic) else list(v)


def test_check_does_not_change_the_settings():
    s = FitSettings(budget=np.int64(5), free=("radius",), sigma=1)
    before = dataclasses.asdict(s)
    s.check()
    assert dataclasses.asdict(s) == before and s.free == ("radius",) and s.sigma == 1
