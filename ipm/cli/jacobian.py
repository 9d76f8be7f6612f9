"""``ipm jacobian GEN ... -o J.npz``: derivatives of the output with respect to every continuous parameter.

Refused before any work: a Jacobian of more than :data:`ipm.jacobian.MAX_ENTRIES` entries (SDF: points x
(parameters + 3); mesh: 3 x vertices x parameters, the vertices counted after ``--subdivide``'s levels: each
level adds one vertex per edge), ``--points``/``--n-points`` for mesh generators (their Jacobian is of their
own vertices), and points whose squares overflow the ``--dtype``. A result with NaN or infinite entries
(float32 overflow) is refused instead of written.
"""

from __future__ import annotations

import io
from pathlib import Path
from typing import TYPE_CHECKING, Annotated

import typer

from ipm.cli.common import (
    DeviceOpt,
    JsonOpt,
    LibraryOpt,
    ParamsOpt,
    PresetOpt,
    RandomOpt,
    SeedOpt,
    SetOpt,
    UsageError,
    check_output,
    emit,
    resolve_device,
    resolve_params,
    resolve_subdivision,
)

if TYPE_CHECKING:
    import numpy as np

# ipm.jacobian.MAX_ENTRIES, for the help text (that module imports torch, which `ipm --help` must not)
MAX_ENTRIES = 2**28

def _load_points(path: Path, dtype: str) -> np.ndarray:
    """The points of a ``.npy`` file: (N, 3), finite, and small enough that squaring a coordinate (every
    distance does) stays finite in ``dtype``."""
    import numpy as np

    from ipm.files import read_npy

    pts = read_npy(path, "points file")
    if pts.ndim != 2 or pts.shape[1] != 3 or len(pts) == 0:
        raise UsageError(f"points file {path}: expected shape (N, 3) with N >= 1, got {pts.shape}")
    if not np.isfinite(pts).all():
        raise UsageError(f"points file {path}: contains NaN or infinite values")
    limit = _largest_coordinate(dtype)
    biggest = float(np.abs(pts).max())
    if biggest > limit:
        raise UsageError(f"points file {path}: expected coordinates of magnitude at most {limit:.3g} for --dtype "
                         f"{dtype} (their squares overflow it), got {biggest:.3g}")
    return pts


def _largest_coordinate(dtype: str) -> float:
    """sqrt of the dtype's largest number, with room for a sum of three squares and a few factors."""
    import numpy as np

    return float(np.sqrt(np.finfo(dtype).max)) / 16


GenArg = Annotated[str, typer.Argument(help="generator name, tree preset, or tree file (.json)")]
OutputOpt = Annotated[Path, typer.Option("-o", "--output", help="output .npz")]
PointsOpt = Annotated[Path | None, typer.Option(help="SDF generators only: points (N, 3) as .npy")]
NPointsOpt = Annotated[int | None, typer.Option("--n-points", help=(
    "SDF generators only: sample N points in the padded bounds [default: 10000]"), show_default=False)]
ModeOpt = Annotated[str, typer.Option(help="auto (the generator's own structured Jacobian when it has one, "
                                           "else forward mode), fwd or rev")]
LodOpt = Annotated[str | None, typer.Option(help="level of detail (mesh generators)")]
SubdivideOpt = Annotated[str | None, typer.Option(help="mesh generators: the Jacobian of the mesh subdivided by "
                                                       "this scheme (loop or midpoint): S J")]
LevelsOpt = Annotated[int, typer.Option(help=(
    "with --subdivide: how many levels, 1 to 6 (each about quadruples the rows; the Jacobian must "
    f"stay within {MAX_ENTRIES:,} entries)"))]
CheckOpt = Annotated[bool, typer.Option(help="compare with float64 central differences")]
DtypeOpt = Annotated[str, typer.Option(help="float32 or float64")]


def register(app: typer.Typer) -> None:
    @app.command()
    def jacobian(
        gen: GenArg,
        output: OutputOpt,
        preset: PresetOpt = None,
        params: ParamsOpt = None,
        set_: SetOpt = None,
        random: RandomOpt = False,
        seed: SeedOpt = 0,
        points: PointsOpt = None,
        n_points: NPointsOpt = None,
        mode: ModeOpt = "auto",
        lod: LodOpt = None,
        subdivide: SubdivideOpt = None,
        levels: LevelsOpt = 1,
        check: CheckOpt = False,
        dtype: DtypeOpt = "float64",
        device: DeviceOpt = "auto",
        library: LibraryOpt = None,
        json_out: JsonOpt = False,
    ) -> None:
        """Jacobian of a generator's output: SDF (N, n+3) w.r.t. parameters and position; mesh (3V, n).

        At most 268,435,456 entries (rows x columns; 2 GiB at float64), checked before any work; --points and
        --n-points apply to SDF generators only."""
        import torch

        from ipm.errors import InputError
        from ipm.generators import get_generator
        from ipm.jacobian import MODES, OUTPUTS, check_entries, output_jacobian

        check_output(output, (".npz",))
        if mode not in MODES:
            raise UsageError(f"--mode: expected one of {', '.join(MODES)}, got {mode!r}")
        scheme = _check_options(dtype, points, n_points, subdivide, levels)
        dev = resolve_device(device)
        dt = getattr(torch, dtype)
        g = get_generator(gen, library=[str(p) for p in library] if library else None)
        field = OUTPUTS[g.kind].takes_points
        if subdivide is not None and field:
            raise UsageError(f"--subdivide: applies to mesh generators; {gen} is an SDF generator")
        for opt, v in (("--points", points), ("--n-points", n_points)):
            if v is not None and not field:
                raise UsageError(f"{opt}: applies to SDF generators; {gen} is a mesh generator, whose Jacobian "
                                 "is of its own vertices")
        values = resolve_params(g, preset, params, set_, random, seed)
        pts = None
        if points is not None:
            loaded = _load_points(points, dtype)
            cols = g.spec.n_continuous + 3
            check_entries(len(loaded), cols, f"points file {points}", f"at most {MAX_ENTRIES // cols:,} points here")
            pts = torch.as_tensor(loaded, dtype=dt, device=dev)
        try:
            res = output_jacobian(g, values, dtype=dt, device=dev, mode=mode, lod=lod, points=pts,
                                  n_points=n_points or 10_000, seed=seed, scheme=scheme, levels=levels, check=check)
        except InputError as e:
            raise UsageError(str(e).replace(f"{g.name} at {len(pts):,} points", f"points file {points}")
                             if pts is not None else str(e)) from None
        _write_npz(output, res, g.split(values, dt, dev)[0])
        result, chk = dict(res.info), res.check
        result["output"] = str(output)
        if check:
            result["max_rel_error"] = chk.max_rel_error
            result["check"] = "ok" if chk.ok(1e-6) else "FAILED (> 1e-6)"
        emit(result, json_out)
        if check and not chk.ok(1e-6):
            raise typer.Exit(1)


def _check_options(dtype: str, points: Path | None, n_points: int | None, subdivide: str | None, levels: int):
    """The options checked before the generator is built; returns ``--subdivide``'s linear scheme or None."""
    if dtype not in ("float32", "float64"):
        raise UsageError(f"--dtype: expected float32 or float64, got {dtype!r}")
    if points is not None and n_points is not None:
        raise UsageError("give one of --points and --n-points, got both")
    if n_points is not None and n_points < 1:
        raise UsageError(f"--n-points: expected a positive count, got {n_points}")
    scheme = resolve_subdivision("--subdivide", subdivide, levels) if subdivide is not None else None
    if scheme is not None and not hasattr(scheme, "operator"):
        raise UsageError(f"--subdivide: {subdivide} is not a linear scheme (its Jacobian is not S J); "
                         "expected loop or midpoint")
    return scheme


def _write_npz(output: Path, res, theta) -> None:
    """``res``'s Jacobian, parameter names, extra arrays and the parameter values ``theta`` as one .npz,
    written atomically."""
    import numpy as np
    import torch

    from ipm.files import write_bytes

    out = {k: (v.cpu().numpy() if torch.is_tensor(v) else v) for k, v in res.arrays.items()}
    out.update(J=res.J.detach().cpu().numpy(), theta=theta.cpu().numpy(), names=np.array(res.names))
    buf = io.BytesIO()
    np.savez_compressed(buf, **out)
    write_bytes(output, buf.getvalue())
