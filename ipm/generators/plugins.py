"""Generators from outside the package: plug-in files and installed packages.

Two ways in, neither edits ipm:

- a Python file, ``ipm --plugin my_gen.py COMMAND ...`` (or the ``IPM_PLUGINS`` environment variable, paths
  joined by ``os.pathsep``; ``--plugin`` adds to it, so the bench's worker processes see the same plug-ins).
  Every :class:`~ipm.generators.base.Generator` subclass the file defines with a ``name`` is registered
  (typically a :class:`~ipm.generators.custom.MeshGenerator` or :class:`~ipm.generators.custom.SdfGenerator`);
  a file may also register members of any registry itself (``register_generator``, a bench method, a loss);
- an installed package with an entry point in the group ``ipm.generators``: ``name = "pkg.module:Class"``
  (a generator class or factory, registered as ``name``) or ``name = "pkg.module"`` (a module that registers
  what it defines when imported).

Plug-ins are loaded when the generator registry is first looked up, after the built-in generators. Each
generator they add is checked once at its defaults (:func:`check_generator`): a mesh of the right shapes,
or distances of the right shape, differentiable in the continuous parameters. A broken plug-in (it does not
import, returns the wrong shapes, is not differentiable, takes a built-in's name) is bad input: one line
naming the file or entry point and the problem.
"""

from __future__ import annotations

import hashlib
import importlib
import importlib.util
import inspect
import logging
import os
import sys
import warnings
from collections.abc import Callable
from pathlib import Path
from types import ModuleType

import torch

from ipm.errors import InputError
from ipm.generators.base import GENERATORS, Generator
from ipm.registry import loading_plugin

log = logging.getLogger(__name__)

ENV = "IPM_PLUGINS"
GROUP = "ipm.generators"
# where each plug-in generator came from, by name (``ipm list generators`` shows it)
SOURCES: dict[str, str] = {}


def add_files(paths: list[str | Path]) -> list[Path]:
    """Add plug-in files (``--plugin``) to ``IPM_PLUGINS`` as absolute paths, checked to exist and end in
    ``.py``; loaded now if the registry has already been looked up, else on its first lookup."""
    files = []
    for raw in paths:
        path = Path(raw).expanduser()
        if path.suffix != ".py":
            raise InputError(f"--plugin {raw}: expected a Python file (.py)")
        if not path.is_file():
            raise InputError(f"--plugin {raw}: no such file")
        files.append(path.resolve())
    known = env_files()
    new = [f for f in files if f not in known]
    os.environ[ENV] = os.pathsep.join(str(f) for f in known + new)
    if GENERATORS.discovered:
        for f in new:
            load_file(f)
    return files


def env_files() -> list[Path]:
    """The plug-in files ``IPM_PLUGINS`` names, in order."""
    return [Path(p) for p in os.environ.get(ENV, "").split(os.pathsep) if p.strip()]


def load_all() -> None:
    """Load the installed plug-ins (entry points), then the plug-in files (the registry's ``after`` hook)."""
    from importlib.metadata import entry_points

    for ep in sorted(entry_points(group=GROUP), key=lambda e: e.name):
        load_entry_point(ep)
    for path in env_files():
        load_file(path)


# discovery imports this module with the other built-in generators; the plug-ins load after them
GENERATORS.after = load_all

_LOADED: dict[Path, ModuleType] = {}


def load_file(path: str | Path) -> list[str]:
    """Import a plug-in file once and register the generators it defines; the names it added."""
    path = Path(path).resolve()
    if path in _LOADED:
        return []
    if not path.is_file():
        raise InputError(f"plug-in {path} ({ENV}): no such file")
    name = f"ipm_plugin_{path.stem}_{hashlib.sha1(str(path).encode()).hexdigest()[:8]}"
    spec = importlib.util.spec_from_file_location(name, path)
    module = importlib.util.module_from_spec(spec)
    sys.modules[name] = module
    source = f"plug-in {path}"
    before = set(GENERATORS.current())
    with loading_plugin(source):
        _run(lambda: spec.loader.exec_module(module), source)
        _LOADED[path] = module
        classes = [obj for obj in vars(module).values() if _is_generator_class(obj, module.__name__)]
        for cls in classes:
            if not any(m is cls for m in GENERATORS.current().values()):
                _add(cls.name, cls, source)
    added = sorted(set(GENERATORS.current()) - before)
    if not added:
        raise InputError(f"{source}: defines no generator (a subclass of ipm.generators.custom.MeshGenerator or "
                         "SdfGenerator with a name, or one registered with register_generator)")
    for gen_name in added:
        SOURCES.setdefault(gen_name, str(path))
        check_generator(gen_name, source)
    return added


def load_entry_point(ep) -> list[str]:
    """Load one ``ipm.generators`` entry point: a module (it registers itself) or a generator class/factory
    (registered as the entry point's name)."""
    dist = getattr(getattr(ep, "dist", None), "name", None)
    source = f"entry point {ep.name} = {ep.value}" + (f" (package {dist})" if dist else "")
    before = set(GENERATORS.current())
    with loading_plugin(source):
        obj = _run(ep.load, source)
        if not isinstance(obj, ModuleType):
            if not callable(obj):
                raise InputError(f"{source}: expected a generator class or factory, got {type(obj).__name__}")
            _add(ep.name, obj, source)
    added = sorted(set(GENERATORS.current()) - before)
    for gen_name in added:
        SOURCES.setdefault(gen_name, source.removeprefix("entry point "))
        check_generator(gen_name, source)
    return added


def _is_generator_class(obj: object, module: str) -> bool:
    return (isinstance(obj, type) and issubclass(obj, Generator) and obj.__module__ == module
            and not inspect.isabstract(obj) and bool(getattr(obj, "name", "")))


def _add(name: str, factory: Callable[[], Generator], source: str) -> None:
    """Register a plug-in generator; a built-in's name is refused (the registry raises, naming ``source``)."""
    if not isinstance(name, str) or not name.replace("_", "").replace("-", "").isalnum():
        raise InputError(f"{source}: generator names are letters, digits, '_' and '-', got {name!r}")
    GENERATORS.add(name, factory)


def _run(fn: Callable, source: str):
    """``fn()``, with an exception of the user's code turned into one line naming ``source`` and where it was
    raised in their file."""
    try:
        return fn()
    except InputError as e:
        raise InputError(f"{source}: {e}") from None
    except Exception as e:  # the plug-in's own code: any error there is its author's to fix
        raise InputError(f"{source}: {type(e).__name__}: {e}{_user_line(e)}") from None


def _user_line(e: BaseException) -> str:
    """`` (file:line)`` of the innermost frame of a traceback outside ipm and the standard library."""
    import traceback

    frames = traceback.extract_tb(e.__traceback__)
    if isinstance(e, SyntaxError) and e.filename:
        return f" ({e.filename}:{e.lineno})"
    ipm_dir = str(Path(__file__).resolve().parents[1])
    user = [f for f in frames if not f.filename.startswith(ipm_dir) and "importlib" not in f.filename]
    return f" ({user[-1].filename}:{user[-1].lineno})" if user else ""


def check_generator(name: str, source: str) -> None:
    """Make the generator ``name`` once and evaluate it at its defaults: right shapes, finite, and
    differentiable in its continuous parameters; a failure is one line naming ``source``."""
    factory = GENERATORS.get(name)
    gen = _run(factory, source)
    if not isinstance(gen, Generator):
        raise InputError(f"{source}: {name} made a {type(gen).__name__}, not an ipm Generator")
    if gen.name != name:
        gen.name = name
    values = _run(lambda: gen.values(), source)
    theta, discrete = gen.split(values)
    theta = theta.clone().requires_grad_(theta.numel() > 0)
    with warnings.catch_warnings():  # torch's warnings about a cut gradient say less than the line below
        warnings.simplefilter("ignore")
        out = _run(lambda: _evaluate(gen, theta, discrete), source)
    if not torch.isfinite(out).all():
        raise InputError(f"{source}: {name} gives non-finite values at its defaults")
    if theta.numel() and (not out.requires_grad or torch.autograd.grad(out.sum(), theta, allow_unused=True)[0]
                          is None):
        raise InputError(f"{source}: {name}'s output is not differentiable in its continuous parameters: build "
                         "it from the tensors in p with torch operations (no float(), .item() or numpy)")


def _mesh_output(gen: Generator, theta: torch.Tensor, discrete: dict) -> torch.Tensor:
    """A mesh generator's output at one point: its vertices."""
    return gen.mesh(theta, discrete).verts


def _sdf_output(gen: Generator, theta: torch.Tensor, discrete: dict) -> torch.Tensor:
    """An SDF generator's output at one point: its distances at 64 seeded points of its box."""
    lo, hi = gen.tree_for(discrete).bounds()
    g = torch.Generator().manual_seed(0)
    pts = torch.as_tensor(lo) + torch.rand(64, 3, generator=g, dtype=torch.float64) * torch.as_tensor(hi - lo)
    return gen.sdf(theta, pts.to(theta.dtype), discrete)


# what a generator of each kind outputs (what check_generator checks)
OUTPUTS = {"mesh": _mesh_output, "sdf": _sdf_output}


def _evaluate(gen: Generator, theta: torch.Tensor, discrete: dict) -> torch.Tensor:
    """The output of a generator at one point (:data:`OUTPUTS`); an unknown kind is refused."""
    if gen.kind not in OUTPUTS:
        raise InputError(f"{gen.name}: kind must be one of {', '.join(OUTPUTS)}, got {gen.kind!r}")
    return OUTPUTS[gen.kind](gen, theta, discrete)
