"""Loud failures: an exception raised inside the objective (a renderer or generator bug) ends a fit with
that exception, whatever the local method and the discrete search strategy, instead of a fit that quietly
returns its start (nlopt turns exceptions inside its callback into stops of its own)."""

from __future__ import annotations

import itertools

import pytest
from boxes import Boxes, boxes_target

from ipm.optim.fit import FitSettings, run_fit
from ipm.render import soft as render

# the pose grid of a silhouette fit takes 16 evaluations: the failure comes later, inside the search
FAIL_AT = 20
LOCAL = ["adam", "mma", "lbfgs"]
DISCRETE = ["memetic", "nlopt", "enumerate", "none"]


@pytest.fixture(scope="module")
def target():
    return boxes_target()


@pytest.mark.parametrize("local, discrete", list(itertools.product(LOCAL, DISCRETE)))
def test_an_error_inside_the_objective_propagates(local, discrete, target, monkeypatch):
    calls, phases = [], []
    real = render.soft_silhouette

    def broken(*args, **kwargs):
        calls.append(1)
        if len(calls) > FAIL_AT:
            raise RuntimeError("injected")
        return real(*args, **kwargs)

    monkeypatch.setattr(render, "soft_silhouette", broken)
    settings = FitSettings(budget=80, seed=0, local=local, discrete=discrete, lr=0.03,
                           search={"memetic": {"population": 4, "refine_steps": 5}, "nlopt": {"refine_steps": 5}})
    with pytest.raises(RuntimeError, match="^injected$") as err:
        run_fit(Boxes(), target, settings, sink=lambda rec: phases.append(rec["phase"]))
    assert type(err.value) is RuntimeError
    assert len(phases) == FAIL_AT and phases[-1] != "init", phases  # it failed in the search, not before


@pytest.mark.parametrize("local", LOCAL)
def test_a_generator_error_propagates_from_the_polish(local, target, monkeypatch):
    calls = []
    real = Boxes.mesh

    def broken(self, theta, discrete, lod=None):
        calls.append(1)
        if len(calls) > 60:
            raise RuntimeError("injected")
        return real(self, theta, discrete, lod)

    monkeypatch.setattr(Boxes, "mesh", broken)
    with pytest.raises(RuntimeError, match="^injected$"):
        run_fit(Boxes(), target, FitSettings(budget=70, seed=0, local=local, discrete="none", polish=0.5))
