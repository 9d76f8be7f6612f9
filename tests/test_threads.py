"""ipm.threads: one thread unless asked, never more than the idle cores, restored after a public call."""

from __future__ import annotations

import subprocess
import sys
import time
from pathlib import Path

import pytest
import torch

from ipm import threads as T
from ipm.errors import InputError
from tests.conftest import run_cli


def test_requested_defaults_to_one_and_reads_the_environment(monkeypatch):
    monkeypatch.delenv(T.ENV, raising=False)
    assert T.requested() == 1
    monkeypatch.setenv(T.ENV, "3")
    assert T.requested() == 3
    assert T.requested(2) == 2  # an explicit count wins


@pytest.mark.parametrize("raw", ["abc", "0", "-2", "1.5", "999"])
def test_a_bad_environment_value_is_bad_input(monkeypatch, raw):
    monkeypatch.setenv(T.ENV, raw)
    with pytest.raises(InputError, match=f"{T.ENV}: expected a whole number of threads in \\[1, {T.MAX}\\]"):
        T.requested()


def test_usable_is_at_most_the_idle_cores(monkeypatch):
    monkeypatch.setattr(T, "cores", lambda: 4)
    monkeypatch.setattr(T, "busy_cores", lambda: 0)
    assert T.usable(2) == 2 and T.usable(8) == 4 and T.usable(1) == 1
    monkeypatch.setattr(T, "busy_cores", lambda: 3)
    assert T.usable(4) == 1
    monkeypatch.setattr(T, "busy_cores", lambda: 9)
    assert T.usable(4) == 1  # never fewer than one
    monkeypatch.setattr(T, "busy_cores", lambda: None)  # no /proc: what was asked, up to the cores
    assert T.usable(3) == 3


def test_running_threads_reads_the_state_after_the_command_name(tmp_path):
    stats = []
    for i, (comm, state) in enumerate([("python", "R"), ("odd) name (x", "R"), ("sleepy", "S")]):
        p = tmp_path / f"{i}.stat"
        p.write_text(f"{100 + i} ({comm}) {state} 1 2 3\n")
        stats.append(p)
    assert T._running_threads(stats) == 2
    assert T._running_threads([tmp_path / "gone.stat"]) == 0


@pytest.mark.skipif(not Path("/proc/loadavg").is_file(), reason="reads Linux's /proc")
def test_busy_cores_counts_other_processes_that_run():
    loops = [subprocess.Popen([sys.executable, "-c", "while True: pass"]) for _ in range(2)]
    try:
        time.sleep(0.5)
        seen = max(T.busy_cores() for _ in range(5))
        assert seen >= 2
        if T.cores() <= 2:
            assert T.usable(2) == 1  # both cores taken: asking for two gets one
    finally:
        for p in loops:
            p.kill()
            p.wait()


def test_a_public_call_runs_with_the_requested_threads_and_restores_the_callers(monkeypatch):
    monkeypatch.delenv(T.ENV, raising=False)
    monkeypatch.setattr(T, "busy_cores", lambda: 0)
    monkeypatch.setattr(T, "cores", lambda: 4)
    seen = []

    @T.one_by_default
    def work():
        seen.append(torch.get_num_threads())

    before = torch.get_num_threads()
    torch.set_num_threads(3)
    try:
        work()
        work(threads=2)
        assert seen == [1, 2]
        assert torch.get_num_threads() == 3
        with pytest.raises(InputError, match="threads: expected a whole number"):
            work(threads=0)
    finally:
        torch.set_num_threads(before)


def test_fits_look_at_the_idle_cores_every_recheck_evaluations(monkeypatch):
    from ipm.optim.evaluator import Evaluator

    calls = []
    monkeypatch.setattr(T, "adapt", lambda: calls.append(1) or 1)
    ev = Evaluator(lambda x, d, g: (x.sum(), torch.ones_like(x) if g else None, {}), 3 * T.RECHECK)
    for _ in range(3 * T.RECHECK):
        ev(torch.zeros(2, dtype=torch.float64), {})
    assert len(calls) == 3


def test_the_command_line_refuses_a_bad_thread_count(monkeypatch, capsys):
    monkeypatch.setenv(T.ENV, "many")
    code, _, err = run_cli(["list", "generators"], capsys)
    assert code == 2
    lines = err.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith(f"ipm: error: {T.ENV}: expected a whole number"), err
    monkeypatch.delenv(T.ENV)
    code, _, err = run_cli(["--threads", "0", "list", "generators"], capsys)
    assert code == 2 and "--threads" in err
