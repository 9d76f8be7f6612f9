"""Programs written by ``ipm generate -o x.scad / x.py`` against ipm's exact mesh (issue #31, ``make table-exports``).

Targets: every shipped tree preset, and the searched trees of the structure table (``results/table_structure/
trees/*.json``) when they are there, else the ten random 3-part truth trees of that table
(:func:`benchmarks.table_structure.make_random`). For each: whether it maps (or which node refuses), the
volume IoU (manifold3d booleans: vol(A ∩ B) / vol(A ∪ B)) of the OpenSCAD program rendered to STL
(``openscad -o x.stl x.scad``, CGAL) and of the CadQuery program's solid exported to STL, each against
:func:`ipm.sdf.exact.exact_mesh` at the same segments, and the seconds each took (writing, running,
exporting). A language whose tool is not installed is skipped, and the table says so. A program that fails
(OpenCascade's booleans raising or leaving an invalid solid, which the CadQuery program's own check reports;
openscad exiting with an error) or whose mesh is not closed and manifold is a row ``{"failed": why}``, counted
in the table, not a crash.

Usage: ``python -m benchmarks.program_exports OUT_DIR [SEGMENTS]``.
"""

from __future__ import annotations

import json
import runpy
import shutil
import subprocess
import sys
import tempfile
import time
from pathlib import Path

from benchmarks.common import commit, machine

SEGMENTS = 64
FINE = 128           # segments of the exact mesh a CadQuery solid (exact curves) is compared with
RESOLUTION = 256     # marching cubes of the exact mesh's nodes without an exact form (round2d, shell2d, ...)
TREES = Path("results/table_structure/trees")
TOLERANCE = 1e-3     # CadQuery's STL: largest distance of the triangles from the B-rep (a 64-gon sags 1.2e-3 r)
ANGULAR = 0.1        # and the largest angle between neighbouring triangles' normals, radians


class ProgramFailed(Exception):
    """A program ran and failed: its tool said why (one line)."""


def targets() -> tuple[list[tuple[str, object]], str]:
    """``([(name, SdfTreeGenerator)], where the searched trees came from)``."""
    from benchmarks.table_structure import make_random
    from ipm.generators import get_generator
    from ipm.generators.sdftree import SdfTreeGenerator, tree_presets
    from ipm.sdf.tree import tree_from_json

    out = [(f"preset {name}", get_generator(name)) for name in tree_presets()]
    files = sorted(TREES.glob("*.json"))
    if files:
        out += [(f"searched {f.stem}", get_generator(str(f))) for f in files]
        return out, f"the searched trees of {TREES}"
    out += [(f"random 3 parts #{s}", SdfTreeGenerator(tree_from_json({"tree": make_random(3, s)})))
            for s in range(10)]
    return out, f"{TREES} absent: the ten random 3-part truth trees of benchmarks/table_structure.py"


def openscad_mesh(text: str, folder: Path):
    """The solid of an OpenSCAD program, rendered to STL by ``openscad`` (trimesh.Trimesh)."""
    import trimesh

    scad, stl = folder / "x.scad", folder / "x.stl"
    scad.write_text(text)
    done = subprocess.run(["openscad", "-o", str(stl), str(scad)], capture_output=True, text=True, timeout=600)
    if done.returncode != 0:
        raise ProgramFailed(f"openscad failed: {done.stderr.strip().splitlines()[-1:]}")
    return trimesh.load(str(stl), force="mesh")


def cadquery_mesh(text: str, folder: Path):
    """The solid of a CadQuery program (its ``result``), exported to STL (trimesh.Trimesh). :class:`ProgramFailed`
    when running it fails in OpenCascade: its own check of the solid (``RuntimeError``), a null shape from a
    boolean (cadquery's ``ValueError``) or OpenCascade's ``Standard_Failure``."""
    import cadquery as cq
    import trimesh
    from OCP.Standard import Standard_Failure

    program, stl = folder / "x.py", folder / "x.stl"
    program.write_text(text)
    try:
        result = runpy.run_path(str(program), run_name="ipm_program")["result"]
    except (RuntimeError, ValueError, Standard_Failure) as e:
        raise ProgramFailed(f"{type(e).__name__}: {str(e).splitlines()[0] if str(e) else '(no message)'}") from e
    cq.exporters.export(result, str(stl), tolerance=TOLERANCE, angularTolerance=ANGULAR)
    return trimesh.load(str(stl), force="mesh")


RUNNERS = {".scad": ("OpenSCAD", "openscad", openscad_mesh), ".py": ("CadQuery", "cadquery", cadquery_mesh)}


def available(suffix: str) -> bool:
    """Whether the tool that runs ``suffix`` programs is installed here."""
    tool = RUNNERS[suffix][1]
    if tool == "openscad":
        return shutil.which("openscad") is not None
    try:
        import cadquery  # noqa: F401
    except ImportError:
        return False
    return True


def reference_segments(suffix: str, segments: int) -> int:
    """The exact mesh's segments a program's solid is compared with: OpenSCAD's own ``$fn``; CadQuery's curves
    are exact (its STL is within :data:`TOLERANCE`), so :data:`FINE`."""
    return segments if suffix == ".scad" else FINE


def score(tree, suffix: str, segments: int = SEGMENTS, reference=None) -> dict:
    """One program of ``tree`` run and compared with the exact mesh at :func:`reference_segments` (or
    ``reference``): ``{iou, seconds}``, ``{refused: line}``, or ``{failed: why, seconds}`` when the program fails
    (:class:`ProgramFailed`) or its mesh is not closed and manifold."""
    from ipm.errors import InputError
    from ipm.io.programs import PROGRAMS, program_text
    from ipm.metrics import volume_iou
    from ipm.sdf.exact import exact_mesh

    t = time.perf_counter()
    try:
        text = program_text(tree, PROGRAMS[suffix], {"generator": "bench"}, segments=segments)
    except InputError as e:
        return {"refused": str(e).split(";")[0]}
    try:
        with tempfile.TemporaryDirectory() as tmp:
            mesh = RUNNERS[suffix][2](text, Path(tmp))
    except ProgramFailed as e:
        return {"failed": str(e), "seconds": round(time.perf_counter() - t, 2)}
    seconds = round(time.perf_counter() - t, 2)
    if reference is None:
        reference = exact_mesh(tree, segments=reference_segments(suffix, segments), resolution=RESOLUTION).mesh
    try:
        return {"iou": round(volume_iou(mesh, reference), 5), "seconds": seconds}
    except InputError as e:  # a mesh (the first: the program's) is not a closed 2-manifold
        return {"failed": str(e), "seconds": seconds}


def run(out_dir: Path, segments: int = SEGMENTS) -> list[dict]:
    """Score every target in both languages; write ``rows.json`` and ``README.md`` in ``out_dir``."""
    from ipm.sdf.exact import exact_mesh

    out_dir.mkdir(parents=True, exist_ok=True)
    found, source = targets()
    rows = []
    for name, gen in found:
        tree = gen.sdf_tree(gen.spec.defaults())
        exact = {s: exact_mesh(tree, segments=reference_segments(s, segments), resolution=RESOLUTION) for s in RUNNERS}
        row = {"target": name, "exact_fallback": list(exact[".scad"].fallback)}
        for suffix, (language, _, _) in RUNNERS.items():
            row[language] = (score(tree, suffix, segments, exact[suffix].mesh) if available(suffix)
                             else {"skipped": "absent"})
        rows.append(row)
        print(json.dumps(row), file=sys.stderr, flush=True)
    (out_dir / "rows.json").write_text(json.dumps(rows, indent=1) + "\n")
    (out_dir / "README.md").write_text(report(rows, source, segments))
    return rows


def _cell(r: dict) -> tuple[str, str]:
    if "refused" in r:
        return f"refused: {r['refused']}", "-"
    if "skipped" in r:
        return "not installed", "-"
    if "failed" in r:
        return f"failed: {r['failed']}", f"{r['seconds']:.2f}"
    return f"{r['iou']:.4f}", f"{r['seconds']:.2f}"


def report(rows: list[dict], source: str, segments: int) -> str:
    """The results page: what was measured, one row per target."""
    lines = [
        "# Programs from SDF trees: OpenSCAD and CadQuery against ipm's exact mesh", "",
        "`make table-exports` (`python -m benchmarks.program_exports results/exports`). Each target's tree is "
        "written as an OpenSCAD program (`ipm generate TREE -o x.scad`) and as a CadQuery program (`-o x.py`); "
        "the OpenSCAD program is rendered to STL by `openscad -o x.stl x.scad` (CGAL), the CadQuery program run "
        f"and its solid exported to STL (tolerance {TOLERANCE}, angular {ANGULAR}). IoU: vol(A ∩ B) / vol(A ∪ B) "
        f"by manifold3d against `ipm.sdf.exact.exact_mesh`: at {segments} segments per circle for OpenSCAD "
        f"(its $fn = {segments}), at {FINE} for CadQuery (its solids' curves are exact, their STL within the "
        "tolerance). Seconds: writing, running and "
        "exporting the program (not the exact mesh). A refusal names the first node without a counterpart; "
        "a failure says why the program failed (OpenCascade's booleans: the CadQuery program checks its solid and "
        "raises when it is not valid) or that its mesh was not closed and manifold.", "",
        f"Targets: every shipped tree preset, and {source}.", "",
        f"Machine: {machine()}; commit {commit()}.", "",
        "| target | OpenSCAD IoU | s | CadQuery IoU | s | exact mesh: nodes by marching cubes |",
        "|---|---|---|---|---|---|"]
    for row in rows:
        (a, sa), (b, sb) = _cell(row["OpenSCAD"]), _cell(row["CadQuery"])
        lines.append(f"| {row['target']} | {a} | {sa} | {b} | {sb} | {', '.join(row['exact_fallback']) or '-'} |")
    lines.append("")
    for language in ("OpenSCAD", "CadQuery"):
        ious = [r[language]["iou"] for r in rows if "iou" in r[language]]
        worst = f", lowest IoU {min(ious):.4f}" if ious else ""
        failed = sum("failed" in r[language] for r in rows)
        lines.append(f"- {language}: {len(ious)} of {len(rows)} targets written and run{worst}; {failed} failed "
                     f"(the program raised or its mesh was not closed and manifold).")
    return "\n".join(lines) + "\n"


if __name__ == "__main__":
    import torch

    torch.set_num_threads(1)
    run(Path(sys.argv[1]) if len(sys.argv) > 1 else Path("results/exports"),
        int(sys.argv[2]) if len(sys.argv) > 2 else SEGMENTS)
