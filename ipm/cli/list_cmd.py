"""``ipm list WHAT``: what the registries hold (every kind of extension; :data:`REGISTRIES`)."""

from __future__ import annotations

import sys
from typing import Annotated

import typer

from ipm.cli.common import JsonOpt, LibraryOpt, UsageError, emit

# the registries listed by name and first docstring line: (module, attribute, help)
REGISTRIES = {
    "strategies": ("ipm.optim.strategies", "STRATEGIES", "discrete search strategies of ipm fit --discrete"),
    "losses": ("ipm.losses", "LOSSES", "mask losses of ipm fit --loss"),
    "terms": ("ipm.optim.terms", "TERMS", "loss terms a fit sums (which apply depends on the target)"),
    "edits": ("ipm.optim.structure.edits", "EDITS", "tree edits of ipm fit --structure search"),
    "methods": ("ipm.bench.methods", "METHODS", "bench methods of experiment files"),
    "meshnodes": ("ipm.generators.meshtree.node", "MESH_NODES", "mesh node types of mesh-tree generators"),
    "schemes": ("ipm.subdiv", "SCHEMES", "subdivision schemes of ipm subdivide --method, ipm fit --subdivide"),
    "converters": ("ipm.convert", "CONVERTERS", "conversion targets of ipm convert --to"),
    "formats": ("ipm.io.export", "EXPORTERS", "mesh file formats written (by suffix)"),
    "programs": ("ipm.io.programs", "PROGRAMS", "CAD program languages an SDF tree is written in (by suffix)"),
    "axes": ("ipm.io.meshes", "UP_AXES", "up axes of --up"),
    "intrinsics": ("ipm.render.camera", "INTRINSICS_FORMATS", "camera intrinsics files read (by suffix)"),
    "shapes": ("ipm.optim.shapes", "SHAPES", "shape adapters of the fit, one per kind of generator"),
}
HELP = {"generators": "procedural generators: kind, parameter counts, presets",
        "nodes": "SDF node types: dimension, children, parameters",
        "presets": "named starting points of every generator and tree",
        "proposals": "shipped proposal networks (ipm fit --init): generator, training command and data",
        **{k: v[2] for k, v in REGISTRIES.items()}}
WHAT = tuple(HELP)


def _members(registry) -> list[dict]:
    """Name and first docstring line (or ``summary``, for members that are instances) of each member of a
    registry."""
    out = []
    for name, member in registry.items():
        doc = (getattr(member, "summary", None) or getattr(member, "__doc__", None) or "").strip().splitlines()
        out.append({"name": name, "doc": doc[0] if doc else ""})
    return out


def _registry(what: str) -> list[dict]:
    import importlib

    module, attr, _ = REGISTRIES[what]
    return _members(getattr(importlib.import_module(module), attr))


def _generators() -> list[dict]:
    from ipm.generators import all_generators
    from ipm.generators.plugins import SOURCES

    out = []
    for name, factory in sorted(all_generators().items()):
        g = factory()
        out.append({"name": name, "kind": g.kind, "continuous": g.spec.n_continuous,
                    "discrete": len(g.spec.discrete), "presets": sorted(g.presets),
                    "description": g.description, "source": SOURCES.get(name, "ipm")})
    return out


def _nodes() -> list[dict]:
    from ipm.sdf.node import NODES

    out = []
    for name, cls in NODES.items():
        doc = (cls.__doc__ or "").strip().splitlines()
        out.append({
            "name": name, "dim": cls.dim or "2|3", "arity": "2+" if cls.arity is None else cls.arity,
            "exact": bool(cls.exact), "macro": hasattr(cls, "template"),
            "params": [p.name for p in cls.param_defs_for(None)],
            "doc": doc[0] if doc else "",
        })
    return out


def _presets() -> list[dict]:
    from ipm.generators import all_generators
    from ipm.generators.base import PRESET_FAMILIES

    out, seen = [], set()
    for family in sorted((f for _, f in PRESET_FAMILIES.items()), key=lambda f: f.order):
        for name in family.names():
            if name not in seen:  # the first family wins a shared name, as in get_generator
                seen.add(name)
                out.append({"generator": family.generator, "preset": name, "use": f"ipm generate {name}"})
    for gname, factory in sorted(all_generators().items()):
        for p in sorted(factory().presets):
            out.append({"generator": gname, "preset": p, "use": f"ipm generate {gname} --preset {p}"})
    return out


def _proposals() -> list[dict]:
    import json

    from ipm.proposals import shipped
    from ipm.proposals.net import load_weights

    out = []
    for path in shipped().values():
        net, extra = load_weights(path)
        s = json.loads(str(extra["settings"])) if "settings" in extra else {}
        out.append({"generator": net.config.generator, "file": f"ipm/proposals/weights/{path.name}",
                    "weights": sum(p.numel() for p in net.parameters()), "samples": s.get("samples"),
                    "steps": s.get("steps"), "command": f"ipm train-proposals {net.config.generator} -o {path.name} "
                    f"--samples {s.get('samples')} --steps {s.get('steps')} --seed {s.get('seed')}"})
    return out


def register(app: typer.Typer) -> None:
    @app.command("list")
    def list_cmd(
        what: Annotated[str | None, typer.Argument(help=", ".join(WHAT))] = None,
        json_out: JsonOpt = False,
        library: LibraryOpt = None,
    ) -> None:
        """List what the registries hold: generators, node types, presets, and every other kind of extension."""
        if what is None:  # what can be listed (cheap: no generator is loaded)
            emit({w: f"ipm list {w}" for w in WHAT} if json_out else
                 "\n".join(f"ipm list {w:<11} {HELP[w]}" for w in WHAT), json_out)
            return
        if what not in WHAT:
            raise UsageError(f"ipm list: expected one of {', '.join(WHAT)}, got {what!r}")
        if library:
            from ipm.sdf.complex import load_library

            load_library([str(p) for p in library])
        special = {"generators": _generators, "nodes": _nodes, "presets": _presets, "proposals": _proposals}
        rows = special[what]() if what in special else _registry(what)
        if json_out:
            emit(rows, True)
            return
        from rich.console import Console
        from rich.table import Table

        table = Table(title=f"ipm {what}")
        for col in rows[0] if rows else []:
            table.add_column(col)
        for r in rows:
            table.add_row(*(", ".join(map(str, v)) if isinstance(v, list) else str(v) for v in r.values()))
        Console(file=sys.stdout, width=160).print(table)
