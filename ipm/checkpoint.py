"""What the package's torch training loops share (:mod:`ipm.subdiv.train`, :mod:`ipm.proposals.train`): checkpoints
as plain arrays (no pickles: Adam's moments and step per named parameter, the network's parameters checked on
loading), so that a resumed run continues bit for bit where it stopped; the check that a resume keeps its settings;
the cosine step-size schedule."""

from __future__ import annotations

import numpy as np
import torch


def adam_arrays(opt: torch.optim.Adam, module: torch.nn.Module) -> dict[str, np.ndarray]:
    """Adam's state of each of ``module``'s parameters as ``adam.m.NAME``, ``adam.v.NAME``, ``adam.t.NAME``."""
    out: dict[str, np.ndarray] = {}
    for k, p in module.named_parameters():
        st = opt.state.get(p)
        if st:
            out[f"adam.m.{k}"] = st["exp_avg"].detach().cpu().numpy()
            out[f"adam.v.{k}"] = st["exp_avg_sq"].detach().cpu().numpy()
            out[f"adam.t.{k}"] = np.array(float(st["step"]))
    return out


def load_adam(opt: torch.optim.Adam, module: torch.nn.Module, arrays: dict) -> None:
    """Restore the state :func:`adam_arrays` wrote into ``opt`` (built over ``module``'s parameters); ``InputError``
    for moments whose shapes are not their parameters' or that are not finite floats, or a step that is not a
    non-negative number."""
    from ipm.errors import InputError

    for k, p in module.named_parameters():
        if f"adam.m.{k}" in arrays:
            for part in ("m", "v"):
                a = np.asarray(arrays[f"adam.{part}.{k}"])
                if tuple(a.shape) != tuple(p.shape) or a.dtype.kind != "f" or not np.isfinite(a).all():
                    raise InputError(f"checkpoint: Adam's state of {k}: expected finite floats of shape "
                                     f"{tuple(p.shape)}, got {a.dtype} {tuple(a.shape)}")
            t = np.asarray(arrays.get(f"adam.t.{k}", np.nan))
            if t.shape != () or t.dtype.kind not in "fiu" or not (np.isfinite(t) and t >= 0):
                raise InputError(f"checkpoint: Adam's step of {k}: expected a non-negative number, got {t!r}")
            opt.state[p] = {"step": torch.tensor(float(arrays[f"adam.t.{k}"])),
                            "exp_avg": torch.as_tensor(np.array(arrays[f"adam.m.{k}"])).clone(),
                            "exp_avg_sq": torch.as_tensor(np.array(arrays[f"adam.v.{k}"])).clone()}


def load_state(module: torch.nn.Module, arrays: dict, what: str) -> None:
    """Load ``module``'s parameters from ``arrays`` (``net.NAME`` each, as the weights files hold them), refusing
    with one line naming ``what`` a parameter that is missing, misshapen, not float or not finite."""
    from ipm.errors import InputError

    state = module.state_dict()
    for k, v in state.items():
        a = arrays.get(f"net.{k}")
        if a is None:
            raise InputError(f"{what}: parameter {k} is missing")
        if tuple(a.shape) != tuple(v.shape) or a.dtype.kind != "f":
            raise InputError(f"{what}: parameter {k}: expected a float array of shape {tuple(v.shape)}, got "
                             f"{a.dtype} {tuple(a.shape)}")
        if not np.isfinite(a).all():
            raise InputError(f"{what}: parameter {k} holds NaN or infinite values")
        state[k] = torch.as_tensor(np.array(a), dtype=v.dtype)
    module.load_state_dict(state)


def same_settings(saved: dict, now: dict) -> None:
    """``InputError`` naming the settings in which a checkpoint's ``saved`` training settings differ from ``now``'s
    (a resume continues one run; other settings are a new run)."""
    from ipm.errors import InputError

    if saved != now:
        diff = sorted(k for k in saved.keys() | now.keys() if saved.get(k) != now.get(k))
        raise InputError(f"resume: the checkpoint was trained with other settings ({', '.join(diff)}); "
                         "start a new run instead")


def cosine_lr(lr: float, step: int, steps: int) -> float:
    """The step size of ``step`` of ``steps``: a cosine from ``lr`` down to ``lr / 20``."""
    import math

    return lr * (0.05 + 0.475 * (1 + math.cos(math.pi * step / max(steps - 1, 1))))
