"""Frozen values handed between stages: meshes, cameras, fit results."""

from __future__ import annotations

import math
import numbers
from collections.abc import Sequence
from dataclasses import dataclass, field

import torch

from ipm.errors import InputError


@dataclass(frozen=True)
class TriMesh:
    """A triangle mesh whose vertices may carry gradients.

    verts: (V, 3) float — positions (row order = Jacobian row order, 3 rows per vertex)
    faces: (F, 3) int64 — counter-clockwise seen from outside
    groups: (F,) int64 or None — part index of every face (see ``group_names``)
    group_names: names of the part indices (walls, windows, handle, ...)
    """

    verts: torch.Tensor
    faces: torch.Tensor
    groups: torch.Tensor | None = None
    group_names: tuple[str, ...] = ()

    def __post_init__(self) -> None:
        if self.verts.ndim != 2 or self.verts.shape[-1] != 3:
            raise InputError(f"verts: expected (V, 3), got {tuple(self.verts.shape)}")
        if self.faces.ndim != 2 or self.faces.shape[-1] != 3:
            raise InputError(f"faces: expected (F, 3), got {tuple(self.faces.shape)}")
        if self.groups is not None and self.groups.shape != self.faces.shape[:1]:
            raise InputError(f"groups: expected ({self.faces.shape[0]},), got {tuple(self.groups.shape)}")

    @property
    def n_verts(self) -> int:
        """Number of vertices V."""
        return int(self.verts.shape[0])

    @property
    def n_faces(self) -> int:
        """Number of faces F."""
        return int(self.faces.shape[0])

    def detach(self) -> TriMesh:
        """The same mesh with vertices cut from the autograd graph (faces and groups shared)."""
        return TriMesh(self.verts.detach(), self.faces, self.groups, self.group_names)

    def to_trimesh(self):
        """A ``trimesh.Trimesh`` (``process=False``: vertex order is kept)."""
        import trimesh

        return trimesh.Trimesh(
            vertices=self.verts.detach().cpu().double().numpy(),
            faces=self.faces.detach().cpu().numpy(),
            process=False,
        )

    @staticmethod
    def from_trimesh(mesh, dtype=torch.float64, device=None) -> TriMesh:
        """A ``TriMesh`` from a ``trimesh.Trimesh`` (vertices as ``dtype``, faces int64; no groups)."""
        return TriMesh(
            torch.as_tensor(mesh.vertices, dtype=dtype, device=device),
            torch.as_tensor(mesh.faces, dtype=torch.int64, device=device),
        )

    @staticmethod
    def concat(parts: Sequence[TriMesh], names: Sequence[str] | None = None) -> TriMesh:
        """Merge meshes (no welding). With ``names``, part i gets group i."""
        verts, faces, groups, offset = [], [], [], 0
        for i, m in enumerate(parts):
            verts.append(m.verts)
            faces.append(m.faces + offset)
            groups.append(torch.full((m.n_faces,), i, dtype=torch.int64, device=m.faces.device))
            offset += m.n_verts
        return TriMesh(
            torch.cat(verts), torch.cat(faces),
            torch.cat(groups) if names is not None else None,
            tuple(names) if names is not None else (),
        )


def _vec3(x, dtype=torch.float64) -> torch.Tensor:
    t = torch.as_tensor(x, dtype=dtype) if not torch.is_tensor(x) else x
    if t.shape != (3,):
        raise InputError(f"expected a 3-vector, got shape {tuple(t.shape)}")
    return t


@dataclass(frozen=True)
class Camera:
    """A pinhole camera (OpenGL convention: looks down -Z in camera space, Y up on screen).

    eye, target, up: (3,) float tensors; fov_deg: () float tensor, vertical field of view in degrees;
    width, height: image size in pixels. Tensors may require grad (poses and FOV can be fitted).
    cx, cy: principal point in pixels (x right, y down; pixel ``(i, j)`` has its center at
    ``(i + 0.5, j + 0.5)``), plain floats; ``None`` is the image center ``width / 2`` (resp.
    ``height / 2``). Pixels are square: the focal length is ``height / (2 tan(fov / 2))`` on both axes.
    """

    eye: torch.Tensor
    target: torch.Tensor
    up: torch.Tensor
    fov_deg: torch.Tensor
    width: int
    height: int
    cx: float | None = None
    cy: float | None = None

    def __post_init__(self) -> None:
        for name in ("eye", "target", "up"):
            object.__setattr__(self, name, _vec3(getattr(self, name)))
        fov = self.fov_deg if torch.is_tensor(self.fov_deg) else torch.tensor(float(self.fov_deg),
                                                                                dtype=self.eye.dtype)
        object.__setattr__(self, "fov_deg", fov)
        if int(self.width) <= 0 or int(self.height) <= 0:
            raise InputError(f"camera image size: expected positive width and height, "
                             f"got {self.width}x{self.height}")
        if not (0.0 < float(fov.detach()) < 180.0):
            raise InputError(f"camera fov_deg: expected a value in (0, 180), got {float(fov.detach())}")
        for name in ("cx", "cy"):
            v = getattr(self, name)
            if v is None:
                continue
            if torch.is_tensor(v) and v.numel() == 1:
                v = v.detach().item()
            if isinstance(v, bool) or not isinstance(v, numbers.Real) or not math.isfinite(v):
                raise InputError(f"camera {name}: expected a finite number of pixels or None (the image "
                                 f"center), got {v!r}")
            object.__setattr__(self, name, float(v))

    @property
    def principal_point(self) -> tuple[float, float]:
        """``(cx, cy)`` in pixels, the image center ``(width / 2, height / 2)`` where unset."""
        return (self.width / 2 if self.cx is None else self.cx,
                self.height / 2 if self.cy is None else self.cy)

    def to_json(self) -> dict:
        """The cameras.json entry; ``cx``, ``cy`` only when set."""
        d = {
            "eye": [float(v) for v in self.eye.detach().cpu().tolist()],
            "target": [float(v) for v in self.target.detach().cpu().tolist()],
            "up": [float(v) for v in self.up.detach().cpu().tolist()],
            "fov_deg": float(self.fov_deg.detach()),
            "width": int(self.width),
            "height": int(self.height),
        }
        for name in ("cx", "cy"):
            if getattr(self, name) is not None:
                d[name] = getattr(self, name)
        return d

    @staticmethod
    def from_json(d: dict) -> Camera:
        """The camera from a cameras.json entry; raises ``InputError`` naming any missing field."""
        need = ("eye", "target", "up", "fov_deg", "width", "height")
        missing = [k for k in need if k not in d]
        if missing:
            raise InputError(f"camera entry is missing {', '.join(missing)}; expected fields {', '.join(need)} "
                             f"(and optionally cx, cy)")
        return Camera(d["eye"], d["target"], d["up"], d["fov_deg"], int(d["width"]), int(d["height"]),
                      d.get("cx"), d.get("cy"))

    def to(self, dtype=None, device=None) -> Camera:
        """A copy with its tensors moved to ``dtype`` / ``device`` (image size and principal point kept)."""
        return Camera(self.eye.to(dtype=dtype, device=device), self.target.to(dtype=dtype, device=device),
                      self.up.to(dtype=dtype, device=device), self.fov_deg.to(dtype=dtype, device=device),
                      self.width, self.height, self.cx, self.cy)


@dataclass(frozen=True)
class FitResult:
    """What every fit returns (``ipm.fit``, ``ipm.fitting.fit_structure``, ``ipm.fitting.fit_shape``): the
    generator and its best parameters, the scores, how it got there, and the result as a mesh in the target's
    own frame (:meth:`mesh`).

    kind: "parametric" (a generator's parameters), "structure" (a tree searched: ``tree``) or "2d" (a 2D tree
    fitted to an image: ``tree``, lifted to 3D where asked); tree: the fitted tree (nested JSON, as its run
    folder's ``tree.json``) for the two tree kinds."""

    generator: str
    params: dict
    loss: float
    evaluations: int
    wall_time_s: float
    scores: dict = field(default_factory=dict)
    run_dir: str | None = None
    # discrete parameters the fit set back to the preset's value because the input could not tell the
    # values apart (a handle hidden behind the body: ipm.optim.fit.break_ties), then the parts (named as
    # Param.adds names them: "handle") whose own parameters it set back to the preset's for the same reason
    tied: tuple[str, ...] = ()
    # discrete values that add parts (Param.adds) the fit took lower than its best loss's because those parts
    # bought too little in a fit to one silhouette (the parsimony rule: ipm.optim.parsimony)
    dropped: tuple[str, ...] = ()
    # the pose as JSON with the turns that map the fitted shape onto itself and the equivalent poses
    # (ipm.optim.problem.Problem.pose_json with symmetry)
    pose: dict = field(default_factory=dict)
    kind: str = "parametric"
    tree: dict | None = None
    # where the fit started (ipm.optim.fit.run_fit): the init mode and the learned proposals it used (their
    # discrete values, probabilities and yaws); their evaluations are recorded as phase "init:learned"
    start: dict = field(default_factory=dict)
    # the result as a mesh in the target's own frame (None where there is none: an unlifted 2D fit)
    shape: TriMesh | None = field(default=None, repr=False, compare=False)

    def mesh(self) -> TriMesh:
        """The fitted shape as a mesh, posed in the target's own frame (as the run folder's ``mesh.obj``)."""
        if self.shape is None:
            raise ValueError(f"a {self.kind} fit without a 3D shape has no mesh")
        return self.shape
