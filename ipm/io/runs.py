"""Run folders: settings, the trajectory (one JSON line per evaluation, flushed as it is written, which
is also the checkpoint), and the final files."""

from __future__ import annotations

import json
import os
from pathlib import Path

from ipm.files import write_text

SETTINGS = "settings.json"
TRAJECTORY = "trajectory.jsonl"
RESULT = "result.json"


class Trajectory:
    """Append-only JSON lines; every record is flushed to disk so a kill loses at most one line."""

    def __init__(self, path: Path, *, keep: int = 0):
        self.path = Path(path)
        self.path.parent.mkdir(parents=True, exist_ok=True)
        if keep == 0 or not self.path.exists():
            self.path.write_text("")
        else:  # rewrite only the first `keep` complete records (drop a torn last line)
            lines = self.path.read_text().splitlines()[:keep]
            write_text(self.path, "".join(line + "\n" for line in lines))
        self._f = open(self.path, "a", buffering=1)

    def __call__(self, record: dict) -> None:
        self._f.write(json.dumps(record, separators=(",", ":")) + "\n")
        self._f.flush()
        os.fsync(self._f.fileno())

    def close(self) -> None:
        self._f.close()


def read_trajectory(path: Path) -> list[dict]:
    """Complete records of a trajectory file (a torn last line is dropped)."""
    out = []
    if not Path(path).is_file():
        return out
    for line in Path(path).read_text().splitlines():
        try:
            out.append(json.loads(line))
        except json.JSONDecodeError:
            break
    return out


def write_json(path: Path, data: dict) -> Path:
    return write_text(path, json.dumps(data, indent=2, default=_default) + "\n")


def _default(o):
    if hasattr(o, "tolist"):
        return o.tolist()
    return str(o)
