"""``ipm demo [OUT_DIR]`` (what ``make demo`` runs): the main jobs on real data (:mod:`ipm.showcase`, each step
the library calls a user makes), their numbers printed, and where the results are."""

from __future__ import annotations

from pathlib import Path
from typing import Annotated

import typer


def register(app: typer.Typer) -> None:
    @app.command("demo")
    def demo(
        out: Annotated[Path, typer.Argument(help="output folder")] = Path("results/demo"),
        budget: Annotated[int, typer.Option(min=1, max=100_000, help="evaluations of the 2-view mug fit")] = 200,
        size: Annotated[int, typer.Option(min=32, max=1024, help="mask size of the 2-view mug fit (pixels)")] = 128,
    ) -> None:
        """The main jobs on real data (../shared/data/real, or $IPM_DATA), in about 1.5 minutes on 2 cores."""
        import torch

        from ipm import showcase as S

        out.mkdir(parents=True, exist_ok=True)
        torch.manual_seed(0)
        print("fitting the dishes generator to 2 masks of a real mug scan ...", flush=True)
        scores = S.fit_real_mug(out, budget, size)
        print(f"  mask IoU on the input views: {', '.join(f'{v:.3f}' for v in scores['input_view_iou'])}")
        print(f"  held-out silhouette IoU (16 views): {scores['heldout_iou_mean']:.3f}")
        print(f"  F-score @0.02 / @0.05: {scores['fscore@0.02']:.3f} / {scores['fscore@0.05']:.3f}, "
              f"Chamfer-L1 {scores['chamfer_l1']:.4f}, 3D IoU {scores['iou_3d']:.3f}")
        print(f"  {scores['evaluations']} evaluations in {scores['wall_time_s']} s")
        print("beyond silhouettes (#13): a photo's mask from a box, and the deferred renderer ...", flush=True)
        b = S.beyond_silhouettes(out)
        print(f"  GrabCut mask of the teal mug in the ClearGrasp photo: {b['mask_pixels']} px in {b['mask_s']} s")
        print(f"  deferred render of the fit ({b['faces']} faces, 256 px), image + gradient w.r.t. vertices: "
              f"{b['render_ms']} ms (gradient norm {b['grad_norm']:.3g})")
        print("  fitting the mug to the photo, its box, depth map and intrinsics ...", flush=True)
        p = S.fit_photo(out)
        print(f"  photo mask IoU {p['photo_iou']:.3f}, median depth error {p['depth_median_mm']:.1f} mm, "
              f"handle {'on, ' + str(p['handle_side']) if p['has_handle'] else 'off'}, camera elevation held at "
              f"{p['ground_elevation_deg']} deg (the table), {p['evaluations']} evaluations in {p['wall_time_s']} s")
        print("subdivision (#14): the fitted mug's coarse mesh, two levels, against its 4x finer surface ...",
              flush=True)
        sub = S.subdivision_showcase(out)
        for name in ("midpoint", "loop", "neural"):
            r = sub[name]
            print(f"  {name:8s} {sub['coarse_vertices']} -> {r['vertices']} vertices in {r['ms']} ms: distance to the "
                  f"finer surface mean {r['mean']:.4f}, max {r['max']:.4f}")
        print("curves and 2D fits (#15): a real bottle's side view, its profile revolved; its outline vectorized ...",
              flush=True)
        cv = S.curves_showcase(out)
        print(f"  profile fit: side-view IoU {cv['profile_iou']:.3f} in {cv['profile_s']} s; revolved against the "
              f"scan: F-score @0.02 {cv['fscore@0.02']:.3f}, Chamfer-L1 {cv['chamfer_l1']:.4f}, "
              f"3D IoU {cv['iou_3d']:.3f}")
        print(f"  outline vectorized in {cv['vectorize_s']} s: {cv['curves']} curve(s) ({cv['closed']} closed), "
              f"{cv['junctions']} junctions, {cv['endpoints']} endpoints; SVG re-rendered IoU {cv['rerender_iou']:.3f}")
        print("structure recovery (#16): the tree of a real armchair searched from its mesh ...", flush=True)
        st = S.structure_showcase(out)
        print(f"  {st['structure']}: {st['nodes']} nodes, held-out silhouette IoU {st['heldout_iou']:.3f}, "
              f"{st['evaluations']} evaluations in {st['wall_time_s']:.0f} s")
        print("editable exports (#31): the armchair's tree as an exact CSG mesh, USD and CAD programs ...", flush=True)
        _print_exports(S.editable_exports(out))
        _learned(S, out)
        print("spout tube and lid knob (#34): a real teapot from one view, both searched, each held off", flush=True)
        for name, r in S.teapot_spout(out).items():
            print(f"  {name:15s} held-out IoU {r['heldout_iou']:.3f} (has_spout {r['has_spout']}, has_knob "
                  f"{r['has_knob']}) in {r['wall_time_s']} s")
        _parsimony(S, out)
        print("universal SDF generator: meshes and Jacobians ...", flush=True)
        for name, r in S.sdf_showcase(out).items():
            print(f"  {name:6s} {r['faces']:7d} faces, watertight={r['watertight']}, Jacobian {r['jacobian']}, "
                  f"max rel. error vs FD {r['max_rel_error_vs_fd']:.1e}")
        print(f"\nResults: {out.resolve()}")
        print("  mug_fit/overlay_000.png, overlay_001.png (target red, fit green), loss.png, result.json, scores.json")
        print("  mug_masks/ (the input masks), sdf/*.glb and *.png (generator meshes and previews)")
        print("  beyond_silhouettes/: photo_mask.png and its overlay; the fit's deferred shading, depth and normals;")
        print("  beyond_silhouettes/photo_fit/overlay_photo.png (the photo fit's outline over the photo), result.json")
        print("  subdivision/mug_{midpoint,loop,neural}.ply and scores.json (distances to the finer surface)")
        print("  curves/: bottle_side.png, profile_overlay.png, bottle_lifted.json (a tree ipm generate loads), "
              "bottle_revolved.obj; outline.png and outline.svg")
        print("  learned_start/: presets/, learned/ and both/ run folders of the house's three fits, scores.json; "
              "fused_views/, teapot/ and parsimony/ alike")
        print("  exports/: armchair_exact.obj (exact CSG), armchair.usda (parameters as customData), armchair.scad and "
              "armchair.py where every node maps")
        print("  structure/: tree.json (the armchair's searched tree, ipm generate loads it), mesh.obj, "
              "structures.jsonl (every tree tried), result.json")


def _learned(S, out: Path) -> None:
    """The learned-proposals steps (:func:`ipm.showcase.learned_start`, :func:`ipm.showcase.fused_views`) and their
    lines."""
    print("learned proposals (#29): a real LoD2 house from one view, started from a preset, from the network's "
          "guesses and from both (the building's default) ...", flush=True)
    for init, r in S.learned_start(out).items():
        counts = ", ".join(f"{k} {v}" for k, v in r["discrete"].items())
        print(f"  from {init:8s} held-out IoU {r['heldout_iou']:.3f} ({counts}) in {r['wall_time_s']} s")
    _fused_views(S, out)


def _fused_views(S, out: Path) -> None:
    """The fused-views step (:func:`ipm.showcase.fused_views`) and its lines: the network's guess from each view and
    from all four fused, and the 4-view fit."""
    print("  the same house from four views: the network's guess from each view alone and from all four ...",
          flush=True)
    rows = S.fused_views(out)
    for name in ("view 1", "view 2", "view 3", "view 4", "fused"):
        r = rows[name]
        counts = ", ".join(f"{k} {r[k]}" for k in ("sections", "floors", "wings", "roof_type"))
        print(f"  {name:6s} {counts}, yaw {r['yaw_deg']} deg, probability {r['probability']:.3g}")
    fit = rows["fit"]
    counts = ", ".join(f"{k} {v}" for k, v in fit["discrete"].items())
    print(f"  fit from the four views: held-out IoU {fit['heldout_iou']:.3f} ({counts}) in {fit['wall_time_s']} s")


def _parsimony(S, out: Path) -> None:
    """The parsimony step (:func:`ipm.showcase.parsimony`) and its lines: each fit's held-out IoU, parts and what the
    rule dropped."""
    print("parsimony (#34): a real sugar bowl from one view, a part kept only where it halves the loss, and not",
          flush=True)
    for name, r in S.parsimony(out).items():
        parts = ", ".join(f"{k} {v}" for k, v in r["parts"].items())
        dropped = f"; dropped {', '.join(r['dropped'])}" if r["dropped"] else ""
        print(f"  {name:14s} held-out IoU {r['heldout_iou']:.3f} ({parts}{dropped}) in {r['wall_time_s']} s")


def _print_exports(ex: dict) -> None:
    """The editable-exports step's lines: the exact mesh, then each program or why it was refused."""
    fallback = f"; marching cubes for {', '.join(ex['fallback'])} (no exact form)" if ex["fallback"] else ""
    print(f"  exact mesh: {ex['vertices']} vertices, watertight={ex['watertight']}{fallback}")
    for suffix, what in ex["programs"].items():
        print(f"  {suffix:5s} {what}")
    if any(w.startswith("refused") for w in ex["programs"].values()):
        print("  (ipm fit --structure search --edits add,replace,delete,merge,mirror,turn searches hard booleans "
              "only, which every program takes)")
