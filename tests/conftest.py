"""Shared fixtures: paths to the real data beside the project, seeded generators."""

from __future__ import annotations

import contextlib
import os
from pathlib import Path

import numpy as np
import pytest
import torch

from ipm import data

ROOT = Path(__file__).resolve().parents[1]
REAL = data.root()  # ../shared/data/real beside the project, or $IPM_DATA (ipm.data: the one place it is named)


def require_file(p: Path) -> Path:
    """``p`` if it exists. Otherwise the test fails under ``CI=true`` (a CI clone without the shared data
    must not pass green) and is skipped, with the reason, on a developer's machine."""
    if not p.is_file():
        msg = f"real data not found: {p} (the tests expect ../shared/data beside the project)"
        if os.environ.get("CI", "").lower() in ("1", "true", "yes"):
            pytest.fail(msg + "; CI=true requires it", pytrace=False)
        pytest.skip(msg)
    return p


def real_path(rel: str) -> Path:
    """A file under ../shared/data/real (:func:`require_file`)."""
    return require_file(REAL / rel)


@contextlib.contextmanager
def throwaway_member(registry, name: str, module_text: str, tmp_path: Path, monkeypatch, package: str):
    """A member ``name`` of ``registry`` defined by one new file in a new package (``package/member.py``),
    the package added to the registry's discovery list: the "one file, no edit elsewhere" promise. On exit
    the member and the package's modules are forgotten, and the test checks the member is gone."""
    import importlib
    import sys
    import textwrap

    folder = tmp_path / "throwaway_lib" / package
    folder.mkdir(parents=True)
    (folder / "__init__.py").write_text("")
    (folder / "member.py").write_text(textwrap.dedent(module_text))
    monkeypatch.syspath_prepend(str(folder.parent))
    importlib.invalidate_caches()
    monkeypatch.setattr(registry, "packages", [*registry.packages, package])
    try:
        yield
    finally:
        registry.remove(name)
        for mod in [m for m in sys.modules if m == package or m.startswith(package + ".")]:
            del sys.modules[mod]
    assert name not in registry


def run_cli(args, capsys) -> tuple[int, str, str]:
    """Run ``ipm`` in this process: ``(exit code, stdout, stderr)``; arguments may be paths."""
    from ipm.cli import main

    with pytest.raises(SystemExit) as e:
        main([str(a) for a in args])
    out, err = capsys.readouterr()
    return e.value.code, out, err


@pytest.fixture
def rng() -> np.random.Generator:
    return np.random.default_rng(1234)


@pytest.fixture(autouse=True)
def _torch_threads(monkeypatch):
    # one thread, as everywhere in ipm (ipm.threads): `make test` runs two workers on two cores, and two
    # OpenMP pools of two threads each wait on each other (fits measured 5-8x slower that way)
    monkeypatch.delenv("IPM_THREADS", raising=False)  # an in-process `ipm --threads N` sets it (ipm.threads.ask)
    torch.set_num_threads(1)
    yield


def write_file(path: Path, content) -> Path:
    """Write ``content`` to ``path`` (its folder made): bytes as they are, a string as text, anything else as
    JSON. Returns ``path``."""
    import json

    path.parent.mkdir(parents=True, exist_ok=True)
    if isinstance(content, bytes):
        path.write_bytes(content)
    else:
        path.write_text(content if isinstance(content, str) else json.dumps(content))
    return path


def tree_files(folder: Path) -> set[str]:
    """The paths below ``folder``, relative to it (empty when it does not exist)."""
    return {str(p.relative_to(folder)) for p in folder.rglob("*")} if folder.exists() else set()


def refusal(case: str, code: int, stdout: str, err: str) -> str:
    """The one line of a refused command (exit 2, one ``ipm: error:`` line on stderr, nothing on stdout), asserted."""
    lines = err.strip().splitlines()
    assert code == 2, f"{case}: exit {code}, stderr: {err}"
    assert len(err.splitlines()) == 1 and lines[0].startswith("ipm: error: "), f"{case}: stderr: {err!r}"
    assert "Traceback" not in err and stdout == "", f"{case}: stdout {stdout!r}"
    return lines[0]
