"""``ipm list generators|nodes|presets|strategies|losses|edits|methods``: what the registries hold."""

from __future__ import annotations

import sys
from typing import Annotated

import typer

from ipm.cli.common import JsonOpt, LibraryOpt, UsageError, emit

WHAT = ("generators", "nodes", "presets", "strategies", "losses", "edits", "methods")
HELP = {"generators": "procedural generators: kind, parameter counts, presets",
        "nodes": "SDF node types: dimension, children, parameters",
        "presets": "named starting points of every generator and tree",
        "strategies": "discrete search strategies of ipm fit --discrete",
        "losses": "mask losses of ipm fit --loss",
        "edits": "tree edits of ipm fit --structure search",
        "methods": "bench methods of experiment files"}


def _members(registry) -> list[dict]:
    """Name and first docstring line of each member of a registry."""
    out = []
    for name, member in registry.items():
        doc = (getattr(member, "__doc__", None) or "").strip().splitlines()
        out.append({"name": name, "doc": doc[0] if doc else ""})
    return out


def _strategies() -> list[dict]:
    from ipm.optim.strategies import STRATEGIES

    return _members(STRATEGIES)


def _losses() -> list[dict]:
    from ipm.losses import LOSSES

    return _members(LOSSES)


def _edits() -> list[dict]:
    from ipm.optim.structure.edits import EDITS

    return _members(EDITS)


def _methods() -> list[dict]:
    from ipm.bench.methods import METHODS

    return _members(METHODS)


def _generators() -> list[dict]:
    from ipm.generators import all_generators

    out = []
    for name, factory in sorted(all_generators().items()):
        g = factory()
        out.append({"name": name, "kind": g.kind, "continuous": g.spec.n_continuous,
                    "discrete": len(g.spec.discrete), "presets": sorted(g.presets),
                    "description": g.description})
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


def register(app: typer.Typer) -> None:
    @app.command("list")
    def list_cmd(
        what: Annotated[str | None, typer.Argument(help=", ".join(WHAT))] = None,
        json_out: JsonOpt = False,
        library: LibraryOpt = None,
    ) -> None:
        """List what the registries hold: generators, node types, presets, strategies, losses, methods."""
        if what is None:  # what can be listed (cheap: no generator is loaded)
            emit({w: f"ipm list {w}" for w in WHAT} if json_out else
                 "\n".join(f"ipm list {w:<11} {HELP[w]}" for w in WHAT), json_out)
            return
        if what not in WHAT:
            raise UsageError(f"ipm list: expected one of {', '.join(WHAT)}, got {what!r}")
        if library:
            from ipm.sdf.complex import load_library

            load_library([str(p) for p in library])
        rows = {"generators": _generators, "nodes": _nodes, "presets": _presets, "strategies": _strategies,
                "edits": _edits, "losses": _losses, "methods": _methods}[what]()
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
