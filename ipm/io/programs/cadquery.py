"""SDF trees as CadQuery programs (Python, ``.py``): exact B-rep solids, no segment count.

One assignment per node, children before their parent, each named after the node's label; the program
ends with ``result``, the tree's solid (CQ-editor shows it; run as a script, it writes ``<file>.step``).
The 2D nodes make planar faces in XY that ``extrude`` and ``revolve`` lift. ipm's shapes that CadQuery
lacks (a plane, ipm's mirror and repeat, a revolve about Y, ...) are small functions defined once at the
top of the file, only those the tree uses. ipm's conventions hold: Y is up, primitives are centered, sizes
are full extents, cylinders and revolutions stand along Y.

OpenCascade's booleans are not exact: where surfaces touch or are tangent they can give an invalid solid or
a valid but wrong one. The programs avoid the causes found on random trees (``benchmarks/cadquery_booleans.py``,
``results/exports/cadquery_booleans.md``): a sphere's poles and seam lie on a slanted axis and a cylinder's or
a cone's seam at an odd azimuth, off the faces of boxes tangent to them along X, Y or Z; unions are not
``.clean()``-ed, since merging their faces can make them invalid. A 3D program ends by checking its solid
(``checked``: ``isValid`` and ``BRepAlgoAPI_Check``, which also finds solids that overlap, and a positive
volume); a failed check raises a ``RuntimeError`` that says OpenCascade's booleans failed and points to the
OpenSCAD export.
"""

from __future__ import annotations

from collections.abc import Callable

from ipm.io.programs import PROGRAMS, ProgramFormat
from ipm.io.programs.lower import Part, Program, bare, fresh, number, registrar, walk

# node type -> fn(part, children's names) -> the expression of the node's shape
NODES: dict[str, Callable[[Part, list[str]], str]] = {}
# node type -> the helper functions (names in HELPERS) its expression calls
USES: dict[str, tuple[str, ...]] = {}

HELPERS = {
    "vec": '''def vec(x, y, z=0.0):
    """A point or direction."""
    return cq.Vector(x, y, z)''',
    "axis": '''def axis(tilt, azimuth):
    """+Y tilted by `tilt` degrees towards the XZ direction at `azimuth` degrees (ipm's rotation axes)."""
    t, a = math.radians(tilt), math.radians(azimuth)
    return vec(math.sin(t) * math.cos(a), math.cos(t), math.sin(t) * math.sin(a))''',
    "polygon": '''def polygon(points):
    """A planar face in XY through the (x, y) points."""
    return cq.Face.makeFromWires(cq.Wire.makePolygon([vec(x, y) for x, y in points], close=True))''',
    "disc": '''def disc(radius_x, radius_y):
    """A circle or an ellipse in XY, centered."""
    if radius_x == radius_y:
        return cq.Face.makeFromWires(cq.Wire.makeCircle(radius_x, vec(0, 0), vec(0, 0, 1)))
    return cq.Face.makeFromWires(cq.Wire.makeEllipse(radius_x, radius_y, vec(0, 0), vec(0, 0, 1), vec(1, 0)))''',
    "round_rect": '''def round_rect(size_x, size_y, radius):
    """ipm's round_rect: a rectangle with its corners rounded by radius (at most just under half the smaller side)."""
    r = min(radius, 0.4999 * min(size_x, size_y))
    face = polygon([(-size_x / 2, -size_y / 2), (size_x / 2, -size_y / 2), (size_x / 2, size_y / 2),
                    (-size_x / 2, size_y / 2)])
    return face.fillet2D(r, face.Vertices()) if r > 0 else face''',
    "ball": '''def ball(radius):
    """A sphere, centered, its poles on a slanted axis: a pole or the seam on another solid's face or edge
    (a box or a cylinder tangent to the sphere along X, Y or Z) is where OpenCascade's booleans fail."""
    return cq.Solid.makeSphere(radius, vec(0, 0, 0), vec(0.5, 0.7, 0.3), angleDegrees1=-90, angleDegrees2=90)''',
    "upright": '''def upright(solid):
    """A solid of revolution made along +Y (a cylinder, a cone) turned about Y so that its seam is not at +Z,
    where a box tangent to it would have a face along the seam (OpenCascade's booleans fail there)."""
    return solid.rotate(vec(0, 0, 0), vec(0, 1, 0), 33.3)''',
    "fused": '''def fused(shapes):
    """The union of shapes (one shape as it is). Not .clean(): merging the faces of a fused solid can leave
    it invalid."""
    return shapes[0].fuse(*shapes[1:]) if len(shapes) > 1 else shapes[0]''',
    "checked": '''def checked(solid):
    """The tree's solid, checked: OpenCascade's booleans can fail on a tree (surfaces that touch or are
    tangent) and give an invalid or empty solid; then this says so rather than hand on a wrong one."""
    from OCP.BRepAlgoAPI import BRepAlgoAPI_Check

    if solid.Volume() <= 0:
        problem = "empty"
    # BRepAlgoAPI_Check also finds solids that overlap (a fuse that kept its operands apart), which isValid passes
    elif not (solid.isValid() and BRepAlgoAPI_Check(solid.wrapped).IsValid()):
        problem = "not valid"
    else:
        return solid
    raise RuntimeError(
        f"OpenCascade's booleans failed for this tree: its solid is {problem} (they can fail where surfaces touch "
        "or are tangent). Export the tree as an OpenSCAD program instead (ipm generate TREE -o x.scad), whose "
        "booleans (CGAL's) are exact.")''',
    "box": '''def box(size_x, size_y, size_z):
    """A box of full sides, centered."""
    return cq.Solid.makeBox(size_x, size_y, size_z, vec(-size_x / 2, -size_y / 2, -size_z / 2))''',
    "round_box": '''def round_box(size_x, size_y, size_z, radius):
    """ipm's round_box: a box with its edges rounded by radius (at most just under half the smallest side)."""
    r = min(radius, 0.4999 * min(size_x, size_y, size_z))
    solid = box(size_x, size_y, size_z)
    return solid.fillet(r, solid.Edges()) if r > 0 else solid''',
    "along_y": '''def along_y(solid):
    """A solid made along Z turned to stand along Y (Z becomes Y)."""
    return solid.rotate(vec(0, 0, 0), vec(1, 0, 0), -90)''',
    "capsule": '''def capsule(radius, height):
    """ipm's capsule: a segment of length `height` along Y swept by a ball of `radius`."""
    ends = [cq.Solid.makeSphere(radius, vec(0, s * height / 2, 0), angleDegrees1=-90, angleDegrees2=90)
            for s in (-1, 1)]
    return cq.Solid.makeCylinder(radius, height, vec(0, -height / 2, 0), vec(0, 1, 0)).fuse(*ends).clean()''',
    "polyhedron": '''def polyhedron(points, faces):
    """A closed solid bounded by planar polygons (faces: corner indices into points)."""
    polygons = [cq.Face.makeFromWires(cq.Wire.makePolygon([vec(*points[i]) for i in f], close=True)) for f in faces]
    return cq.Solid.makeSolid(cq.Shell.makeShell(polygons)).fix()''',
    "scaled": '''def scaled(shape, sx, sy, sz=1.0):
    """A shape scaled by its own factor along each axis."""
    return shape.transformGeometry(cq.Matrix([[sx, 0, 0, 0], [0, sy, 0, 0], [0, 0, sz, 0]]))''',
    "half_space": '''def half_space(axis_index, offset):
    """The side coordinate[axis_index] >= offset, as a cube of side BIG."""
    corner = [-BIG / 2] * 3
    corner[axis_index] = offset
    return cq.Solid.makeBox(BIG, BIG, BIG, vec(*corner))''',
    "plane": '''def plane(tilt, azimuth, offset):
    """ipm's plane: the half-space below the plane n . p = offset, n = +Y tilted by tilt towards azimuth."""
    below = cq.Solid.makeBox(BIG, BIG, BIG, vec(-BIG / 2, offset - BIG, -BIG / 2))
    a = math.radians(azimuth)
    return below.rotate(vec(0, 0, 0), vec(math.sin(a), 0, -math.cos(a)), tilt)''',
    "mirrored": '''def mirrored(shape, axis_index, offset):
    """ipm's mirror: the part of shape at coordinate[axis_index] >= offset and its reflection across that plane."""
    kept = shape.intersect(half_space(axis_index, offset))
    base = [0, 0, 0]
    base[axis_index] = offset
    return kept.fuse(kept.mirror(("YZ", "XZ", "XY")[axis_index], vec(*base)))''',
    "repeated": '''def repeated(shape, axis_index, count, spacing):
    """ipm's repeat: count copies along an axis, spacing apart, centered at the origin."""
    copies = []
    for i in range(count):
        step = [0, 0, 0]
        step[axis_index] = (i - (count - 1) / 2) * spacing
        copies.append(shape.translate(vec(*step)))
    return fused(copies)''',
    "extruded": '''def extruded(shape, height):
    """ipm's extrude: a 2D shape in XY as a slab of full `height` along Z, centered."""
    slabs = [cq.Solid.extrudeLinear(f, vec(0, 0, height)) for f in shape.Faces()]
    return fused(slabs).translate(vec(0, 0, -height / 2))''',
    "revolved": '''def revolved(shape, offset):
    """ipm's revolve: the 2D shape's part at x >= -offset, moved out by offset, turned about the Y axis."""
    kept = shape.translate(vec(offset, 0)).intersect(polygon([(0, -BIG), (BIG, -BIG), (BIG, BIG), (0, BIG)]))
    return fused([cq.Solid.revolve(f, 360, vec(0, 0), vec(0, 1)) for f in kept.Faces()])''',
    "revolution": '''def revolution(height, radii):
    """ipm's revolution: radii at evenly spaced heights from y = 0 to `height`, turned about Y."""
    k = len(radii)
    profile = [(0, 0)] + [(r, height * i / (k - 1)) for i, r in enumerate(radii)] + [(0, height)]
    return cq.Solid.revolve(polygon(profile), 360, vec(0, 0), vec(0, 1))''',
}

# the helpers a helper calls
_NEEDS = {"axis": ("vec",), "ball": ("vec",), "upright": ("vec",),
          "polygon": ("vec",), "round_rect": ("polygon", "vec"), "disc": ("vec",),
          "box": ("vec",), "round_box": ("box", "vec"), "along_y": ("vec",), "capsule": ("vec",),
          "polyhedron": ("vec",),
          "half_space": ("vec",), "plane": ("vec",), "mirrored": ("half_space", "vec"),
          "repeated": ("fused", "vec"), "extruded": ("fused", "vec"), "revolved": ("fused", "polygon", "vec"),
          "revolution": ("polygon", "vec")}


# registers the writer of these node types' expressions (calling the helper functions ``uses``)
node = registrar(NODES, USES)


for _kind, _text, _uses in (
    ("sphere", "ball({radius})", ("ball",)),
    ("box", "box({size_x}, {size_y}, {size_z})", ("box",)),
    ("round_box", "round_box({size_x}, {size_y}, {size_z}, {radius})", ("round_box",)),
    ("cylinder", "upright(cq.Solid.makeCylinder({radius}, {height}, vec(0, -{height} / 2, 0), vec(0, 1, 0)))",
     ("upright",)),
    ("cone", "upright(cq.Solid.makeCone({radius_bottom}, {radius_top}, {height}, vec(0, -{height} / 2, 0), "
     "vec(0, 1, 0)))", ("upright",)),
    ("capsule", "capsule({radius}, {height})", ("capsule",)),
    ("torus", "cq.Solid.makeTorus({major}, {minor}, vec(0, 0, 0), vec(0, 1, 0))", ("vec",)),
    ("hex_prism", "along_y(cq.Solid.extrudeLinear(polygon([({radius} / math.cos(math.pi / 6) * math.cos(i * math.pi "
     "/ 3), {radius} / math.cos(math.pi / 6) * math.sin(i * math.pi / 3)) for i in range(6)]), vec(0, 0, {height}))"
     ".translate(vec(0, 0, -{height} / 2)))", ("along_y", "polygon")),
    ("tri_prism", "extruded(polygon([(0, {radius}), (-math.sin(math.pi / 3) * {radius}, -{radius} / 2), "
     "(math.sin(math.pi / 3) * {radius}, -{radius} / 2)]), {length})", ("extruded", "polygon")),
    ("pyramid", "polyhedron([(-{base} / 2, 0, -{base} / 2), ({base} / 2, 0, -{base} / 2), ({base} / 2, 0, {base} / 2), "
     "(-{base} / 2, 0, {base} / 2), (0, {height}, 0)], [(0, 1, 2, 3), (0, 4, 1), (1, 4, 2), (2, 4, 3), (3, 4, 0)])",
     ("polyhedron",)),
    ("octahedron", "polyhedron([({radius}, 0, 0), (-{radius}, 0, 0), (0, {radius}, 0), (0, -{radius}, 0), "
     "(0, 0, {radius}), (0, 0, -{radius})], [(0, 2, 4), (0, 5, 2), (0, 4, 3), (0, 3, 5), (1, 4, 2), (1, 2, 5), "
     "(1, 3, 4), (1, 5, 3)])", ("polyhedron",)),
    ("ellipsoid", "scaled(ball(1), {radius_x}, {radius_y}, {radius_z})", ("scaled", "ball")),
    ("plane", "plane({tilt}, {azimuth}, {offset})", ("plane",)),
    ("circle", "disc({radius}, {radius})", ("disc",)),
    ("ellipse", "disc({radius_x}, {radius_y})", ("disc",)),
    ("rect", "polygon([(-{size_x} / 2, -{size_y} / 2), ({size_x} / 2, -{size_y} / 2), ({size_x} / 2, {size_y} / 2), "
     "(-{size_x} / 2, {size_y} / 2)])", ("polygon",)),
    ("round_rect", "round_rect({size_x}, {size_y}, {radius})", ("round_rect",)),
    ("triangle", "polygon([({x0}, {y0}), ({x1}, {y1}), ({x2}, {y2})])", ("polygon",)),
):
    node(_kind, uses=_uses)(lambda part, kids, _text=_text: _text.format(**part.args))


@node("wind_rose", uses=("polygon",))
def _wind_rose(part: Part, kids) -> str:
    """The eight radii on the rays at 0, 45, ..., 315 degrees."""
    radii = ", ".join(str(part[f"r{i}"]) for i in range(8))
    return f"polygon([(r * math.cos(i * math.pi / 4), r * math.sin(i * math.pi / 4)) for i, r in enumerate([{radii}])])"


@node("polygon", uses=("polygon",))
def _polygon(part: Part, kids) -> str:
    """A closed polygon through its points."""
    points = (f"({part['x' + str(i)]}, {part['y' + str(i)]})" for i in range(part.size))
    return f"polygon([{', '.join(points)}])"


@node("revolution", uses=("revolution",))
def _revolution(part: Part, kids) -> str:
    """The radii as one list."""
    return f"revolution({part['height']}, [{', '.join(str(part[f'r{i}']) for i in range(part.size))}])"


node("union", "union_n", uses=("fused",))(lambda p, kids: f"fused([{', '.join(kids)}])")
node("intersection")(lambda p, kids: f"{kids[0]}.intersect({kids[1]})")
node("subtraction")(lambda p, kids: f"{kids[0]}.cut({kids[1]})")
node("translate", uses=("vec",))(lambda p, kids: f"{kids[0]}.translate(vec({p['x']}, {p['y']}, {p['z']}))")
node("translate2d", uses=("vec",))(lambda p, kids: f"{kids[0]}.translate(vec({p['x']}, {p['y']}))")
node("scale", "scale2d")(lambda p, kids: f"{kids[0]}.scale({p['factor']})")
node("scale3", uses=("scaled",))(lambda p, kids: f"scaled({kids[0]}, {p['sx']}, {p['sy']}, {p['sz']})")
node("place", uses=("vec",))(
    lambda p, kids: f"{kids[0]}.scale({p['unit']}).translate(vec({p['x']}, {p['y']}, {p['z']}))")
node("place2d", uses=("vec",))(lambda p, kids: f"{kids[0]}.scale({p['unit']}).translate(vec({p['x']}, {p['y']}))")
node("rotate", uses=("axis",))(
    lambda p, kids: f"{kids[0]}.rotate(vec(0, 0, 0), axis({p['tilt']}, {p['azimuth']}), {p['angle']})")
node("rotate2d", uses=("vec",))(lambda p, kids: f"{kids[0]}.rotate(vec(0, 0, 0), vec(0, 0, 1), {p['angle']})")
node("mirror", uses=("mirrored",))(
    lambda p, kids: f"mirrored({kids[0]}, {int(p['axis'].value)}, {p['offset']})")
node("repeat", uses=("repeated",))(
    lambda p, kids: f"repeated({kids[0]}, {int(p['axis'].value)}, {p['count']}, {p['spacing']})")
node("extrude", uses=("extruded",))(lambda p, kids: f"extruded({kids[0]}, {p['height']})")
node("revolve", uses=("revolved",))(lambda p, kids: f"revolved({kids[0]}, {p['offset']})")


class _Names:
    """Statement names: each part's label as an identifier, made unique against the variables'."""

    def __init__(self, taken):
        self.taken = set(taken)

    def __call__(self, label: str) -> str:
        return fresh(label, self.taken)


def statements(part: Part, names: _Names, out: list[str]) -> str:
    """Append the assignments of a part's children, then its own, to ``out``; the part's name."""
    kids = [statements(c, names, out) for c in part.children]
    name = names(part.label)
    note = part.note if part.note and part.note != name else ""  # a name that says it all needs no comment
    out.append(f"{name} = {NODES[part.kind](part, kids)}" + (f"  # {note}" if note else ""))
    return name


def helpers(program: Program) -> list[str]:
    """The helper functions the program calls, each once, in :data:`HELPERS`' order."""
    want = {h for p in walk(program.root) for h in USES[p.kind]} | ({"checked"} if program.root.dim == 3 else set())
    want |= {n for h in want for n in _NEEDS.get(h, ())}
    return [HELPERS[h] for h in HELPERS if h in want]


def write(program: Program, segments: int, header: list[str]) -> str:
    """The whole ``.py`` file: header, imports, parameters, helper functions, one assignment a node."""
    used = helpers(program)
    lines = ['"""' + header[0] + "."] + [""] + header[1:] + ['"""', "", "import math", "", "import cadquery as cq", ""]
    if any("BIG" in text for text in used):
        lines += [f"BIG = {number(program.big)}  # the side of the cubes that stand for half-spaces", ""]
    lines.append("# parameters")
    for name, val, comment in program.variables:
        lines.append(f"{name} = {bare(val.text)}" + (f"  # {comment}" if comment else ""))
    for text in used:
        lines += ["", "", text]
    body: list[str] = []
    root = statements(program.root, _Names(name for name, _, _ in program.variables), body)
    result = f"checked({root})" if program.root.dim == 3 else root
    lines += ["", "", "# the shape, part by part"] + body + [
        f"result = {result}", "", "if \"show_object\" in globals():  # CQ-editor", "    show_object(result)",
        "elif __name__ == \"__main__\":", "    cq.exporters.export(result, __file__.rsplit(\".\", 1)[0] + \".step\")"]
    return "\n".join(lines) + "\n"


PROGRAMS.add(".py", ProgramFormat("CadQuery", "#", NODES, write))
