"""Universal generator speed: SDF evaluation, gradient, full Jacobian and meshing of the classic CSG
example (sphere ∩ box − three cylinders), float32, 2 threads; beside it, where installed, the same solid in
fogleman/sdf (https://github.com/fogleman/sdf, NumPy, float64: its own choice), evaluated on the same points (issue
#30: every figure side by side in one run). fogleman/sdf is not on PyPI (the ``sdf`` package there is another
project): ``pip install git+https://github.com/fogleman/sdf``; where it does not import, its row says so."""

from __future__ import annotations

from pathlib import Path

import torch

from benchmarks.common import timeit, write_results


def hand_written(p: torch.Tensor) -> torch.Tensor:
    """The same solid as plain torch expressions: the floor for any interpreter."""
    x, y, z = p[:, 0], p[:, 1], p[:, 2]
    s = torch.linalg.vector_norm(p, dim=-1) - 0.65
    q = p.abs() - 0.5
    b = torch.linalg.vector_norm(q.clamp(min=0), dim=-1) + q.amax(-1).clamp(max=0)

    def cyl(u, v, w):
        d1 = torch.sqrt(u * u + w * w) - 0.3
        d2 = v.abs() - 0.6
        return torch.sqrt(d1.clamp(min=0) ** 2 + d2.clamp(min=0) ** 2) + torch.maximum(d1, d2).clamp(max=0)

    c = torch.minimum(torch.minimum(cyl(x, y, z), cyl(y, z, x)), cyl(z, x, y))
    return torch.maximum(torch.maximum(s, b), -c)


def run(out_dir: Path) -> list[dict]:
    from ipm.generators import get_generator
    from ipm.jacobian import sdf_jacobian
    from ipm.sdf.meshing import mesh_sdf

    torch.manual_seed(0)
    tree = get_generator("csg").tree
    n = tree.n_params
    theta = tree.theta(torch.float32)
    p6 = torch.rand(1_000_000, 3) * 2.4 - 1.2
    p5 = p6[:100_000].contiguous()
    rows = []

    with torch.no_grad():
        t_fwd = timeit(lambda: tree.sdf(theta, p6))
        t_hand = timeit(lambda: hand_written(p6))
    rows.append({"measure": "SDF eval, 1e6 points (tree)", "seconds": t_fwd,
                 "rate": f"{1e6 / t_fwd / 1e6:.1f} M points/s", "ratio": "1.0x (reference)",
                 "target": ">= 20 M points/s", "ok": 1e6 / t_fwd >= 20e6})
    rows.append({"measure": "SDF eval, 1e6 points (hand-written torch)", "seconds": t_hand,
                 "rate": f"{1e6 / t_hand / 1e6:.1f} M points/s", "ratio": f"{t_hand / t_fwd:.2f}x of tree",
                 "target": "-", "ok": "-"})

    def grad_step():
        th = theta.clone().requires_grad_(True)
        torch.sigmoid(-tree.sdf(th, p6) / 0.02).mean().backward()

    t_grad = timeit(grad_step, repeat=5)
    rows.append({"measure": "gradient of a scalar loss, 1e6 points", "seconds": t_grad,
                 "rate": "-", "ratio": f"{t_grad / t_fwd:.2f}x forward", "target": "<= 5x forward",
                 "ok": t_grad <= 5 * t_fwd})

    with torch.no_grad():
        t_fwd5 = timeit(lambda: tree.sdf(theta, p5))
    for mode in ("rev", "fwd", "auto"):
        t_j = timeit(lambda: sdf_jacobian(tree.sdf, theta, p5, mode), repeat=3)
        rows.append({"measure": f"Jacobian 1e5 x {n + 3} (mode {mode})", "seconds": t_j, "rate": "-",
                     "ratio": f"{t_j / t_fwd5:.1f}x forward (limit {2 * (n + 3)}x)",
                     "target": f"<= 2(n+3) = {2 * (n + 3)}x forward", "ok": t_j <= 2 * (n + 3) * t_fwd5})

    lo, hi = tree.bounds()
    mesh = None

    def do_mesh():
        nonlocal mesh
        mesh = mesh_sdf(lambda q: tree.sdf(None, q), lo, hi, 256)

    t_mesh = timeit(do_mesh, repeat=3)
    tm = mesh.to_trimesh()
    rows.append({"measure": "meshing at 256^3 (narrow band + marching cubes)", "seconds": t_mesh,
                 "rate": f"{mesh.n_faces} faces, watertight={tm.is_watertight}", "ratio": "-",
                 "target": "<= 1.0 s, watertight", "ok": t_mesh <= 1.0 and tm.is_watertight})
    rows.append(_fogleman_row(p6, t_fwd))
    write_results(out_dir, "sdf", "Universal generator: classic CSG example, float32", rows)
    return rows


def _fogleman_row(points: torch.Tensor, t_tree: float) -> dict:
    """fogleman/sdf's evaluation of the same solid at the same points (module docstring), checked against the
    hand-written one."""
    row = {"measure": "SDF eval, 1e6 points (fogleman/sdf)", "target": "-", "ok": "-"}
    try:
        import sdf as fsdf

        a, b, c = (fsdf.capped_cylinder(-0.6 * axis, 0.6 * axis, 0.3) for axis in (fsdf.X, fsdf.Y, fsdf.Z))
        f = (fsdf.sphere(0.65) & fsdf.box(1.0)) - (a | b | c)
    except (ImportError, AttributeError) as e:
        return {**row, "seconds": "-", "rate": "-", "ratio": f"skipped: {type(e).__name__}: {e}"}
    p = points.double().numpy()
    t = timeit(lambda: f(p), repeat=3)
    err = float(abs(f(p[:10_000]).ravel() - hand_written(points[:10_000].double()).numpy()).max())
    return {**row, "seconds": t, "rate": f"{1e6 / t / 1e6:.2f} M points/s",
            "ratio": f"{t / t_tree:.1f}x of tree (values within {err:.1e} of the hand-written solid)"}
