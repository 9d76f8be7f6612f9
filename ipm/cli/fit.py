"""``ipm fit GEN (--masks DIR [--depth DIR] [--parts DIR] | --image PHOTO (--mask MASK | --box BOX) [--depth FILE]
[--intrinsics FILE] | --target-mesh MESH) ... -o RUN_DIR``; ``ipm fit [START.json] --structure search
(--target-mesh MESH | --masks DIR) -o RUN_DIR``: the tree's structure searched too."""

from __future__ import annotations

import sys
from pathlib import Path
from types import SimpleNamespace
from typing import Annotated

import typer

from ipm.cli.common import DeviceOpt, JsonOpt, LibraryOpt, PresetOpt, SeedOpt, UsageError, emit, resolve_device

# ipm fit's options, declared once here so that the command reads as its list of options
GenArg = Annotated[str | None, typer.Argument(help="generator name, tree preset, or tree file (.json); "
    "with --resume, the run's own")]
OutputOpt = Annotated[Path | None, typer.Option("-o", "--output", help="run folder")]
MasksOpt = Annotated[Path | None, typer.Option(help="mask folder: view_000.png ... + cameras.json")]
TargetMeshOpt = Annotated[Path | None, typer.Option("--target-mesh", help="mesh to match (Chamfer)")]
UpOpt = Annotated[str, typer.Option(help="up axis of --target-mesh: y or z")]
DepthOpt = Annotated[Path | None, typer.Option(help=(
    "depth maps: with --masks a folder of depth_000.npy (scene units) or depth_000.png (16-bit mm) ...; "
    "with --image the photo's depth map"))]
DepthScaleOpt = Annotated[float, typer.Option("--depth-scale", help=(
    "scene units per step of a 16-bit depth PNG (0.001: millimetres to metres)"))]
PartsOpt = Annotated[Path | None, typer.Option(help=(
    "part labels: a folder of part_000.png ... and parts.json naming the label values"))]
ImageOpt = Annotated[Path | None, typer.Option(help=(
    "a photo to fit (one view; the camera is fitted, with --intrinsics its pose only)"))]
MaskOpt = Annotated[Path | None, typer.Option(
    help="the photo's foreground mask (PNG, soft 0..255 allowed)")]
BoxOpt = Annotated[str | None, typer.Option(help=(
    "X0,Y0,X1,Y1: a box around the object in the photo, segmented with GrabCut (instead of --mask)"))]
IntrinsicsOpt = Annotated[Path | None, typer.Option(help=(
    "the photo's camera: JSON {fx, fy, cx, cy, width, height} or a YAML as ClearGrasp ships it"))]
SizeOpt = Annotated[int, typer.Option(help="photo: pixels a side of the square crop the fit sees")]
ShapeOpt = Annotated[Path | None, typer.Option(help=(
    "a binary image (PNG, shape > 127) to fit a 2D tree to (GEN: a tree file with a 2D root): the shape "
    "itself, or with --profile a body of revolution's side view"))]
ProfileOpt = Annotated[bool, typer.Option("--profile", help=(
    "--shape: the image is the side silhouette of revolve(tree); the fit is the profile, lifted to 3D "
    "by revolve (lifted.json, mesh.obj)"))]
ExtrudeOpt = Annotated[float | None, typer.Option(help=(
    "--shape: lift the fitted 2D shape to 3D by extrude with this height, in the tree's units"))]
StepsOpt = Annotated[int, typer.Option(help="--shape: Adam steps of the 2D fit")]
GroundOpt = Annotated[bool, typer.Option("--ground/--no-ground", help=(
    "photo with depth and intrinsics: hold the camera's elevation at the plane the object stands on, "
    "measured in the depth around it"))]
DepthWeightOpt = Annotated[float, typer.Option("--depth-weight", help="weight of the depth loss")]
PartsWeightOpt = Annotated[float, typer.Option("--parts-weight", help="weight of the part-label loss")]
ImageWeightOpt = Annotated[float, typer.Option("--image-weight", help="weight of the shading loss")]
CameraOpt = Annotated[str, typer.Option(help="known (cameras.json) or fit (recover elevation, "
    "distance, FOV)")]
DiscreteOpt = Annotated[str, typer.Option(help="discrete search strategy (ipm list strategies)")]
InitOpt = Annotated[str | None, typer.Option(help=(
    "where the search starts: presets (the pose grid and the generator's presets), learned (a trained network's "
    "proposals from the masks: ipm list proposals; the pose grid runs on the most probable) or both "
    "(the proposals ranked with the presets); default: the generator's (building: both; others: presets)"))]
ProposalsOpt = Annotated[Path | None, typer.Option(help=(
    "proposal weights (ipm train-proposals); default: those shipped for the generator"))]
BudgetOpt = Annotated[int | None, typer.Option(help=(
    "function evaluations (one render + loss each; --structure search: one Adam step or score of a "
    "tree) (default 1500; --structure search: 16000)"))]
LossOpt = Annotated[str, typer.Option(help=(
    "mask loss (ipm list losses: iou, mse, sinkhorn, sliced) or a weighted sum such as iou+0.5*sinkhorn; "
    "the transport losses pull masks that do not overlap together"))]
BlurOpt = Annotated[float | None, typer.Option(help=(
    "sinkhorn: entropic blur, a share of the image's longer side (default 0.05)"))]
DustbinOpt = Annotated[float | None, typer.Option(help=(
    "sinkhorn: partial transport; mass farther than this share of the image from the other mask is "
    "left unmatched (for a target the generator cannot explain whole)"))]
LocalOpt = Annotated[str, typer.Option(help="gradient refinement: adam, mma or lbfgs (nlopt)")]
LrOpt = Annotated[float | None, typer.Option(help="Adam learning rate in normalized parameter space "
    "(default: the generator's, 0.005 for dishes, else 0.02)")]
NloptAlgorithmOpt = Annotated[str, typer.Option("--nlopt-algorithm",
    help="GN_CRS2_LM, GN_ESCH or GN_ISRES")]
FixOpt = Annotated[list[str] | None, typer.Option(help="NAME=VALUE held fixed, repeatable")]
RangeOpt = Annotated[list[str] | None, typer.Option(
    "--range", help="NAME=LO:HI search a discrete parameter only in [LO, HI], repeatable")]
NoPoseOpt = Annotated[bool, typer.Option("--no-pose", help="keep the object pose fixed")]
PriorOpt = Annotated[float, typer.Option(help="weight of a pull towards the starting preset")]
PartCostOpt = Annotated[float | None, typer.Option("--part-cost", help=(
    "loss added per part a discrete value adds (a handle, a wing): a part stays only where it "
    "lowers the loss by more (default 0)"))]
PartRatioOpt = Annotated[float | None, typer.Option("--part-ratio", help=(
    "one silhouette alone: the parts a fit's discrete values add stay only where they bring the loss below this "
    "share of the best fit without them; 1 keeps the lower loss (default: the generator's, dishes 0.5)"))]
AnchorOpt = Annotated[float | None, typer.Option(help=(
    "single view without depth: loss per unit of normalized distance an anchored parameter (a "
    "vessel section's aspect and squareness) moves from the start (default 0.02; 0 frees them)"))]
SubdivideOpt = Annotated[str | None, typer.Option(help=(
    "mesh generators: render the generator's mesh subdivided by loop, midpoint or neural instead of "
    "as it is (pair with --lod low)"))]
SubdivideLevelsOpt = Annotated[int, typer.Option("--subdivide-levels", help="levels of --subdivide (1-3)")]
LodOpt = Annotated[str | None, typer.Option(help="mesh generators: level of detail (low, medium, high)")]
SdfSilhouetteOpt = Annotated[str, typer.Option("--sdf-silhouette", help=(
    "SDF generators: silhouettes of a marching-cubes mesh made differentiable by the implicit function "
    "theorem (mesh, the default) or sphere-traced pixel by pixel (trace: the reference, 2.5 to 3.5x slower)"))]
PolishOpt = Annotated[float | None, typer.Option(help=(
    "share of the budget for the final refinement of the best candidates with every parameter free "
    "(default 0.15; a photo's details: 0.4)"))]
StructureOpt = Annotated[str, typer.Option(help=(
    "fixed: fit GEN's parameters; search: search the tree itself (which primitives, joined how) and its "
    "parameters, from --target-mesh or --masks of 2+ views, starting from GEN (a tree file) if given; "
    "writes tree.json, which ipm generate loads"))]
EditsOpt = Annotated[str | None, typer.Option(help=(
    "--structure search: the edits it may propose, comma-separated (ipm list edits; default all). Leave out "
    "smooth for a tree of hard booleans, which ipm generate --mesher exact meshes and -o x.scad / x.py exports"))]
ResumeOpt = Annotated[Path | None, typer.Option(help="continue an interrupted run folder")]


def register(app: typer.Typer) -> None:
    @app.command()
    def fit(
        gen: GenArg = None,
        output: OutputOpt = None,
        masks: MasksOpt = None,
        target_mesh: TargetMeshOpt = None,
        up: UpOpt = "y",
        depth: DepthOpt = None,
        depth_scale: DepthScaleOpt = 0.001,
        parts: PartsOpt = None,
        image: ImageOpt = None,
        mask: MaskOpt = None,
        box: BoxOpt = None,
        intrinsics: IntrinsicsOpt = None,
        size: SizeOpt = 128,
        shape: ShapeOpt = None,
        profile: ProfileOpt = False,
        extrude: ExtrudeOpt = None,
        steps: StepsOpt = 400,
        ground: GroundOpt = True,
        depth_weight: DepthWeightOpt = 1.0,
        parts_weight: PartsWeightOpt = 1.0,
        image_weight: ImageWeightOpt = 1.0,
        camera: CameraOpt = "known",
        discrete: DiscreteOpt = "memetic",
        init: InitOpt = None,
        proposals: ProposalsOpt = None,
        budget: BudgetOpt = None,
        seed: SeedOpt = 0,
        preset: PresetOpt = None,
        loss: LossOpt = "iou",
        blur: BlurOpt = None,
        dustbin: DustbinOpt = None,
        local: LocalOpt = "adam",
        lr: LrOpt = None,
        nlopt_algorithm: NloptAlgorithmOpt = "GN_CRS2_LM",
        fix: FixOpt = None,
        range_: RangeOpt = None,
        no_pose: NoPoseOpt = False,
        prior: PriorOpt = 0.0,
        part_cost: PartCostOpt = None,
        part_ratio: PartRatioOpt = None,
        anchor: AnchorOpt = None,
        subdivide: SubdivideOpt = None,
        subdivide_levels: SubdivideLevelsOpt = 1,
        lod: LodOpt = None,
        sdf_silhouette: SdfSilhouetteOpt = "mesh",
        polish: PolishOpt = None,
        structure: StructureOpt = "fixed",
        edits: EditsOpt = None,
        resume: ResumeOpt = None,
        library: LibraryOpt = None,
        device: DeviceOpt = "auto",
        json_out: JsonOpt = False,
    ) -> None:
        """Recover continuous and discrete parameters from masks or a mesh."""
        _run(SimpleNamespace(**locals()))


def _run(o: SimpleNamespace) -> None:
    """``ipm fit`` with its options ``o``: a structure search, a 2D fit, or a fit of GEN's parameters."""
    if o.structure not in ("fixed", "search"):
        raise UsageError(f"--structure: expected fixed or search, got {o.structure!r}")
    if o.structure == "search" or (o.resume is not None and _is_structure_run(o.resume)):
        others = [n for n, v in (("--image", o.image), ("--depth", o.depth), ("--parts", o.parts),
                                 ("--shape", o.shape), ("--preset", o.preset)) if v is not None]
        if others:
            raise UsageError(f"--structure search: takes a mesh or masks only; got {' and '.join(others)}")
        _fit_structure(o.gen, o.target_mesh, o.up, o.masks, o.output, o.resume, o.budget, o.seed, o.device, o.json_out,
                       edits=o.edits)
        return
    if o.edits is not None:
        raise UsageError("--edits: expected with --structure search (the edits of the structure search)")
    o.budget = FIT_BUDGET if o.budget is None else o.budget
    if o.shape is not None or o.profile or o.extrude is not None:
        if o.shape is None:
            raise UsageError("--profile and --extrude: expected with a 2D fit's --shape IMAGE")
        others = [n for n, v in (("--masks", o.masks), ("--target-mesh", o.target_mesh), ("--image", o.image),
                                 ("--resume", o.resume)) if v is not None]
        if others:
            raise UsageError(f"--shape: a 2D fit takes no other target; got {' and '.join(others)}")
        if o.gen is None or o.output is None:
            raise UsageError("--shape: expected ipm fit TREE.json --shape IMAGE -o RUN_DIR")
        _fit_2d(o.gen, o.shape, o.output, profile=o.profile, extrude=o.extrude, steps=o.steps, loss=o.loss,
                transport={k: v for k, v in (("blur", o.blur), ("dustbin", o.dustbin)) if v is not None},
                seed=o.seed, json_out=o.json_out)
        return
    _check_parametric(o)
    _fit_parametric(o)


def _check_parametric(o: SimpleNamespace) -> None:
    """The options of a fit of GEN's parameters that need no library to be refused: one target, the photo's
    mask or box, files that exist, a run folder that is new, empty or resumed."""
    from ipm.optim import discrete as D

    if o.resume is None and o.output is None:
        raise UsageError("expected -o RUN_DIR (or --resume RUN_DIR)")
    if o.resume is not None and o.output is not None and o.output != o.resume:
        raise UsageError("--resume RUN_DIR continues that folder; leave out -o or give the same folder")
    if o.gen is None and o.resume is None:  # --resume alone: the run's own generator (ipm.fitting.fit)
        raise UsageError("expected a generator: ipm fit GEN ... (see ipm list generators)")
    given = [n for n, v in (("--masks", o.masks), ("--target-mesh", o.target_mesh), ("--image", o.image))
             if v is not None]
    if o.resume is None and len(given) != 1:
        raise UsageError("expected exactly one target: --masks DIR, --image PHOTO or --target-mesh MESH; got "
                         + (" and ".join(given) if given else "none"))
    if o.image is not None and (o.mask is None) == (o.box is None):
        raise UsageError("--image: expected the photo's --mask MASK.png or a --box X0,Y0,X1,Y1 around the "
                         "object (ipm mask makes a mask from a box), one of them; got "
                         + ("both" if o.mask is not None else "neither"))
    for name, v in (("--mask", o.mask), ("--box", o.box), ("--intrinsics", o.intrinsics)):
        if v is not None and o.image is None:
            raise UsageError(f"{name}: expected with a photo (--image PHOTO), got no --image")
    for name, path in (("--image", o.image), ("--mask", o.mask), ("--intrinsics", o.intrinsics)):
        if path is not None and not path.is_file():
            raise UsageError(f"{name}: file not found: {path}")
    for name, path in (("--depth", o.depth), ("--parts", o.parts)):
        if path is not None and not path.exists():
            raise UsageError(f"{name}: not found: {path}")
    if o.budget < 1:
        raise UsageError(f"--budget: expected at least 1 evaluation, got {o.budget}")
    if o.up not in ("y", "z"):
        raise UsageError(f"--up: expected y or z, got {o.up!r}")
    if o.nlopt_algorithm not in D.NLOPT_GLOBAL:
        raise UsageError(f"--nlopt-algorithm: expected one of {', '.join(D.NLOPT_GLOBAL)}, "
                         f"got {o.nlopt_algorithm!r}")
    if o.masks is not None and not o.masks.is_dir():
        raise UsageError(f"--masks: folder not found: {o.masks}")
    if o.target_mesh is not None and not o.target_mesh.is_file():
        raise UsageError(f"--target-mesh: file not found: {o.target_mesh}")
    if o.output is not None and o.output.exists() and not o.output.is_dir():
        raise UsageError(f"run folder {o.output} is a file; expected a new or empty folder")
    if o.output is not None and o.output.exists() and o.resume is None and any(o.output.iterdir()):
        raise UsageError(f"run folder {o.output} exists and is not empty; choose a new folder or --resume it")


def _fit_parametric(o: SimpleNamespace) -> None:
    """A fit of GEN's parameters (:func:`ipm.fitting.fit`) with a progress bar on a terminal; its scores on stdout."""
    from ipm.fitting import fit as run
    from ipm.params import parse_assignment

    fixed = dict(parse_assignment(s) for s in o.fix or [])
    ranges = {}
    for item in o.range_ or []:
        name, _, span = item.partition("=")
        lo, _, hi = span.partition(":")
        try:
            ranges[name.strip()] = [int(lo), int(hi)]
        except ValueError:
            raise UsageError(f"--range: expected NAME=LO:HI with integers, got {item!r}") from None
    box_px = None
    if o.box is not None:
        from ipm.segment import parse_box

        box_px = parse_box(o.box)
    dev = resolve_device(o.device)
    from rich.progress import BarColumn, Progress, TextColumn, TimeElapsedColumn

    bar = Progress(TextColumn("{task.fields[phase]:<18}"), BarColumn(), TextColumn("{task.completed}/{task.total}"),
                   TextColumn("loss {task.fields[loss]:.4f}  IoU {task.fields[iou]}"), TimeElapsedColumn(),
                   transient=True, console=__import__("rich.console").console.Console(stderr=True))
    task = bar.add_task("fit", total=o.budget, phase="start", loss=float("nan"), iou="-")

    started = []

    def progress(ev):
        if not started:  # shown from the first evaluation: bad input fails before, with one line
            started.append(bar.console.is_terminal)  # elsewhere a bar leaves only an empty line
            if started[0]:
                bar.start()
        iou = ev.last.get("iou")
        bar.update(task, completed=ev.count, total=ev.budget, phase=ev.phase[:18], loss=min(ev.best.loss, 9e9),
                   iou="-" if iou is None else f"{min(iou):.3f}")

    try:
        result = run(o.gen, masks=o.masks, target_mesh=o.target_mesh, up=o.up, depth=o.depth,
                     depth_scale=o.depth_scale, parts=o.parts, image=o.image, mask=o.mask, box=box_px,
                     intrinsics=o.intrinsics, photo_size=o.size, ground=o.ground,
                     depth_weight=o.depth_weight, parts_weight=o.parts_weight, image_weight=o.image_weight,
                     run_dir=o.resume or o.output,
                     resume=o.resume is not None, library=[str(p) for p in o.library] if o.library else None,
                     progress=progress, device=dev, budget=o.budget, seed=o.seed, discrete=o.discrete,
                     init=o.init, proposals=None if o.proposals is None else str(o.proposals),
                     camera=o.camera,
                     loss=o.loss, local=o.local, lr=o.lr, preset=o.preset, fix=fixed, ranges=ranges,
                     pose=not o.no_pose,
                     prior_weight=o.prior, search={"nlopt": {"algorithm": o.nlopt_algorithm}},
                     subdivide=o.subdivide, subdivide_levels=o.subdivide_levels, lod=o.lod,
                     sdf_silhouette=o.sdf_silhouette,
                     transport={k: v for k, v in (("blur", o.blur), ("dustbin", o.dustbin)) if v is not None},
                     **{k: v for k, v in (("polish", o.polish), ("part_cost", o.part_cost),
                                          ("part_ratio", o.part_ratio), ("anchor", o.anchor))
                        if v is not None})
    finally:
        if started and started[0]:
            bar.stop()
    out = {"run": result.run_dir, "loss": result.loss, "evaluations": result.evaluations,
           "wall_time_s": round(result.wall_time_s, 2), **{k: v for k, v in result.scores.items()}}
    if result.pose:  # the yaw up to the fitted shape's symmetry: free (a body of revolution) or a set
        out["yaw_deg"] = round(result.pose["yaw_deg"], 3)
        out["yaw_free"] = result.pose.get("yaw_free", False)
        if not out["yaw_free"]:
            out["equivalent_yaws_deg"] = [round(e["yaw_deg"], 3) for e in result.pose.get("equivalent", [])]
    emit(out, o.json_out)
    sys.stdout.flush()


def _fit_2d(tree_file: str, image: Path, output: Path, *, profile: bool, extrude: float | None, steps: int,
            loss: str, transport: dict, seed: int, json_out: bool) -> None:
    """``ipm fit TREE.json --shape IMAGE [--profile | --extrude H] -o RUN_DIR``: :func:`ipm.fitting.fit_shape`."""
    from ipm.errors import InputError
    from ipm.fitting import fit_shape

    if not tree_file.endswith(".json"):
        raise UsageError(f"--shape: expected a tree file (.json) with a 2D root, got {tree_file!r}")
    if not image.is_file():
        raise UsageError(f"--shape: file not found: {image}")
    if steps < 1:
        raise UsageError(f"--steps: expected at least 1, got {steps}")
    if profile and extrude is not None:
        raise UsageError("--profile and --extrude: a profile is lifted by revolve; give one of them")
    if extrude is not None and not (0 < extrude < float("inf")):
        raise UsageError(f"--extrude: expected a positive height, got {extrude}")
    try:
        res = fit_shape(tree_file, image, run_dir=output, profile=profile, extrude=extrude, steps=steps, loss=loss,
                        transport=transport, seed=seed)
    except InputError as e:
        raise UsageError(str(e) if str(e).startswith("run folder") else f"--shape {image}: {e}") from None
    emit({"run": res.run_dir, **{k: res.scores[k] for k in ("mode", "iou")}, "loss": res.loss,
          "seconds": res.scores["seconds"], "pose": res.scores["pose"]}, json_out)


FIT_BUDGET = 1500


def _is_structure_run(run_dir: Path) -> bool:
    """Whether ``run_dir``'s settings.json is a structure search's; a damaged one is refused later, by the
    fit's resume, naming it."""
    from ipm.errors import InputError
    from ipm.io.runs import read_json_file

    try:
        saved = read_json_file(run_dir / "settings.json", "run settings")
    except (OSError, InputError):
        return False
    return isinstance(saved, dict) and "structure" in saved


def _fit_structure(start: str | None, target_mesh: Path | None, up: str, masks: Path | None, output: Path | None,
                   resume: Path | None, budget: int, seed: int, device: str, json_out: bool, *,
                   edits: str | None = None) -> None:
    """``ipm fit --structure search``: :func:`ipm.fitting.fit_structure` with a progress bar."""
    from rich.console import Console
    from rich.progress import BarColumn, Progress, TextColumn, TimeElapsedColumn

    from ipm.fitting import fit_structure

    if resume is None:
        if output is None:
            raise UsageError("expected -o RUN_DIR (or --resume RUN_DIR)")
        given = [n for n, v in (("--masks", masks), ("--target-mesh", target_mesh)) if v is not None]
        if len(given) != 1:
            raise UsageError("--structure search: expected one target, --target-mesh MESH or --masks DIR; got "
                             + (" and ".join(given) if given else "none"))
        if target_mesh is not None and not target_mesh.is_file():
            raise UsageError(f"--target-mesh: file not found: {target_mesh}")
        if masks is not None and not masks.is_dir():
            raise UsageError(f"--masks: folder not found: {masks}")
        if start is not None and not Path(start).is_file():
            raise UsageError(f"--structure search: GEN is the tree file to start from; file not found: {start}")
        if up not in ("y", "z"):
            raise UsageError(f"--up: expected y or z, got {up!r}")
        if output.exists() and (not output.is_dir() or any(output.iterdir())):
            raise UsageError(f"run folder {output} exists and is not an empty folder; choose a new folder or "
                             "--resume it")
    elif output is not None and output != resume:
        raise UsageError("--resume RUN_DIR continues that folder; leave out -o or give the same folder")
    elif edits is not None:
        raise UsageError("--edits: a resumed search keeps the edits it was started with; leave out --edits")
    from ipm.optim.structure import StructureSettings

    if budget is not None and budget < 1:
        raise UsageError(f"--budget: expected at least 1 evaluation, got {budget}")
    budget = StructureSettings().budget if budget is None else budget
    dev = resolve_device(device)
    bar = Progress(TextColumn("structure round {task.fields[round]:<3}"), BarColumn(),
                   TextColumn("{task.completed}/{task.total}"), TextColumn("IoU {task.fields[iou]}"),
                   TimeElapsedColumn(), transient=True, console=Console(stderr=True))
    task = bar.add_task("structure", total=budget, round=0, iou="-")
    started = []

    def progress(used: int, total: int, info: dict) -> None:
        if not started:
            started.append(bar.console.is_terminal)  # elsewhere a bar leaves only an empty line
            if started[0]:
                bar.start()
        q = info.get("iou")
        bar.update(task, completed=used, total=total, round=info.get("round", 0),
                   iou="-" if q is None or q != q else f"{q:.3f}")

    try:
        if resume is not None:
            res = fit_structure(run_dir=resume, resume=True, progress=progress, device=dev)
        else:
            chosen = {} if edits is None else {"edits": tuple(e.strip() for e in edits.split(",") if e.strip())}
            res = fit_structure(target_mesh=target_mesh, up=up, masks=masks, start=start, run_dir=output,
                                progress=progress, device=dev, budget=budget, seed=seed, **chosen)
    finally:
        if started and started[0]:
            bar.stop()
    emit({**res.scores, "evaluations": res.evaluations, "wall_time_s": round(res.wall_time_s, 3),
          "run": res.run_dir}, json_out)
    sys.stdout.flush()
