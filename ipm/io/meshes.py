"""Loading target meshes: read with trimesh, convert the up axis to Y, normalize (DESIGN.md's protocol).

The evaluation protocol (v2) normalizes every target: up axis first, then the bounding box's center goes
to the origin and one uniform scale puts the farthest vertex at distance 1 (the unit bounding sphere).
Vertex order is kept (``process=False``); scenes (GLB) are flattened into one mesh with their transforms
applied.
"""

from __future__ import annotations

import logging
import warnings
from collections.abc import Callable
from pathlib import Path

import numpy as np
import torch

from ipm.errors import InputError
from ipm.registry import Registry
from ipm.types import TriMesh

log = logging.getLogger(__name__)

MESH_SUFFIXES = (".ply", ".obj", ".stl", ".glb", ".gltf", ".off")


def _y_up(v: torch.Tensor) -> torch.Tensor:
    """Y is up already: the vertices as they are."""
    return v


def _z_up(v: torch.Tensor) -> torch.Tensor:
    """Z up: rotated -90 degrees about X, (x, y, z) -> (x, z, -y) (right-handed stays right-handed)."""
    return torch.stack([v[:, 0], v[:, 2], -v[:, 1]], 1)


# Up-axis conversions to the project's Y-up convention, by the name given with ``--up`` (another axis is one
# more ``UP_AXES.add(name, fn)``)
UP_AXES: Registry[Callable[[torch.Tensor], torch.Tensor]] = Registry("up axis")
UP_AXES.add("y", _y_up)
UP_AXES.add("z", _z_up)


def to_y_up(verts: torch.Tensor, up: str) -> torch.Tensor:
    """Vertices (V, 3) rotated so that the axis named ``up`` ("y" or "z") becomes +Y."""
    try:
        return UP_AXES[up.lower()](verts)
    except (KeyError, InputError, AttributeError):
        raise InputError(f"up axis: expected one of {', '.join(UP_AXES)}, got {up!r}") from None


def normalize_mesh(mesh: TriMesh) -> TriMesh:
    """The mesh in the evaluation protocol's frame: bounding-box center at the origin, farthest vertex
    at distance 1 (both over the vertices that faces use; :func:`ipm.metrics.unit_sphere_frame`).

    Raises ``ValueError`` for an empty mesh or one whose vertices are all at one point.
    """
    from ipm.metrics import unit_sphere_frame

    if mesh.n_verts == 0 or mesh.n_faces == 0:
        raise InputError(f"normalize: expected a mesh with faces, got {mesh.n_verts} vertices and "
                         f"{mesh.n_faces} faces")
    used = mesh.verts[torch.unique(mesh.faces)].detach().cpu().double().numpy()
    center, scale = unit_sphere_frame(used)
    verts = (mesh.verts - torch.as_tensor(center, dtype=mesh.verts.dtype, device=mesh.verts.device)) * scale
    return TriMesh(verts, mesh.faces, mesh.groups, mesh.group_names)


def surface_area(mesh: TriMesh) -> float:
    """Total triangle area of the mesh."""
    v = mesh.verts.detach().double()[mesh.faces]
    return float(torch.linalg.vector_norm(torch.linalg.cross(v[:, 1] - v[:, 0], v[:, 2] - v[:, 0]), dim=-1)
                 .sum() / 2) if mesh.n_faces else 0.0


def unreadable(path: Path, e: Exception) -> str:
    """The message for a mesh file trimesh cannot read: the file, the formats read, and trimesh's reason
    where it is about the file (not where trimesh reached for a module it lacks: an ASCII STL of
    garbage sends it looking for ``charset_normalizer`` to guess the text's encoding)."""
    why = str(e).splitlines()[0].strip() if str(e).strip() else ""
    about_file = why and not isinstance(e, (ImportError, AttributeError, TypeError, RecursionError)) \
        and len(why) <= 200
    return (f"mesh file {path}: expected a readable mesh ({', '.join(MESH_SUFFIXES)}), got a file that is not "
            f"a valid {path.suffix.lower() or 'mesh'} file" + (f" ({type(e).__name__}: {why})" if about_file else ""))


def load_mesh(path: str | Path, *, up: str = "y", normalize: bool = True,
              dtype: torch.dtype = torch.float64) -> TriMesh:
    """Read a mesh file (.ply, .obj, .stl, .glb, .gltf, .off) as a Y-up :class:`~ipm.types.TriMesh`.

    up: the file's up axis ("y" or "z"); normalize: to the protocol's unit bounding sphere
    (:func:`normalize_mesh`). Raises ``ValueError`` ("expected ..., got ...") for a missing or unreadable file
    (:func:`unreadable`: the formats read), an unknown format, or a mesh without triangles or area.
    """
    import trimesh

    path = Path(path)
    if not path.is_file():
        raise InputError(f"mesh file: expected an existing file, got {path}")
    if path.suffix.lower() not in MESH_SUFFIXES:
        raise InputError(f"mesh file {path}: expected a suffix among {', '.join(MESH_SUFFIXES)}, "
                         f"got {path.suffix or '(none)'}")
    if up.lower() not in UP_AXES:
        raise InputError(f"up axis: expected one of {', '.join(UP_AXES)}, got {up!r}")
    kwargs = {"skip_materials": True} if path.suffix.lower() in (".obj", ".ply") else {}
    try:
        with warnings.catch_warnings():  # a broken file's numpy warnings (NaN, overflow) would be a second line
            warnings.simplefilter("ignore")
            tm = trimesh.load_mesh(str(path), process=False, **kwargs)
            faces = np.asarray(getattr(tm, "faces", np.zeros((0, 3))), dtype=np.int64).reshape(-1, 3)
            verts = np.asarray(getattr(tm, "vertices", np.zeros((0, 3))), dtype=np.float64).reshape(-1, 3)
    except MemoryError:
        raise
    except Exception as e:  # trimesh raises many kinds of errors for broken files (a vertex "v 1 2" too)
        raise InputError(unreadable(path, e)) from None
    if len(faces) == 0:
        raise InputError(f"mesh file {path}: expected triangles, got none")
    if faces.min() < 0 or faces.max() >= len(verts):
        raise InputError(f"mesh file {path}: expected vertex indices in [0, {len(verts)}) in its faces, got "
                         f"[{int(faces.min())}, {int(faces.max())}]")
    if not np.isfinite(verts).all():
        raise InputError(f"mesh file {path}: expected finite vertex coordinates, got NaN or inf")
    mesh = TriMesh(to_y_up(torch.as_tensor(verts, dtype=dtype), up), torch.as_tensor(faces))
    if surface_area(mesh) <= 0:
        raise InputError(f"mesh file {path}: expected a mesh with nonzero surface area, got zero-area "
                         f"triangles only")
    log.debug("loaded %s: %d vertices, %d faces", path, mesh.n_verts, mesh.n_faces)
    return normalize_mesh(mesh) if normalize else mesh
