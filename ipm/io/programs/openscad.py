"""SDF trees as OpenSCAD programs (``.scad``).

One statement per node, nested as the tree is; ipm's shapes that OpenSCAD lacks (a capsule, a pyramid, a
plane, ipm's mirror and repeat, a revolve about Y, ...) are modules declared once at the top of the file,
only those the tree uses. ipm's conventions hold: Y is up, primitives are centered, sizes are full
extents, cylinders and revolutions stand along Y (OpenSCAD's stand along Z: ``rotate([-90, 0, 0])`` turns
Z into Y). Curves have ``$fn`` straight pieces a circle.
"""

from __future__ import annotations

from collections.abc import Callable

from ipm.io.programs import PROGRAMS, ProgramFormat
from ipm.io.programs.lower import Part, Program, bare, number, registrar, walk

# node type -> fn(part, children's lines) -> the node's lines
NODES: dict[str, Callable[[Part, list[list[str]]], list[str]]] = {}
# node type -> the helper modules (names in MODULES) its statement calls
USES: dict[str, tuple[str, ...]] = {}

MODULES = {
    "axis": """// +Y tilted by `tilt` degrees towards the XZ direction at `azimuth` degrees (ipm's rotation axes)
function axis(tilt, azimuth) = [sin(tilt) * cos(azimuth), cos(tilt), sin(tilt) * sin(azimuth)];""",
    "along_y": """// OpenSCAD's solids of revolution stand along Z; ipm's along Y
module along_y() { rotate([-90, 0, 0]) children(); }""",
    "half_space": """// the side of the plane through the origin that the unit vector v points to (a cube of side big)
module half_space(v) { translate(big / 2 * v) cube(big, center = true); }""",
    "plane": """// ipm's plane: the half-space below the plane n . p = offset, n = +Y tilted by tilt towards azimuth
module plane(tilt, azimuth, offset) {
  rotate(a = tilt, v = [sin(azimuth), 0, -cos(azimuth)]) translate([0, offset - big / 2, 0]) cube(big, center = true);
}""",
    "mirror_half": """// ipm's mirror: the children's part at v . p >= offset and its reflection across that plane
module mirror_half(v, offset) {
  translate(offset * v) {
    intersection() { translate(-offset * v) children(); half_space(v); }
    mirror(v) intersection() { translate(-offset * v) children(); half_space(v); }
  }
}""",
    "repeat": """// ipm's repeat: count copies along the unit vector v, spacing apart, centered at the origin
module repeat(v, count, spacing) {
  for (i = [0 : count - 1]) translate((i - (count - 1) / 2) * spacing * v) children();
}""",
    "revolve": """// ipm's revolve: the 2D children's part at x >= -offset, moved out by offset, turned about the Y axis
module revolve(offset) {
  along_y() rotate_extrude() intersection() {
    translate([offset, 0]) children();
    translate([0, -big / 2]) square(big);
  }
}""",
    "capsule": """// ipm's capsule: a segment of length `height` along Y swept by a ball of `radius`
module capsule(radius, height) {
  along_y() rotate_extrude() intersection() {
    hull() for (s = [-1, 1]) translate([0, s * height / 2]) circle(r = radius);
    translate([0, -big / 2]) square(big);
  }
}""",
    "round_box": """// ipm's round_box: a box of full sides `size`, edges rounded by `radius` (a box grown by a ball)
module round_box(size, radius) {
  r = min(radius, min(size) / 2);
  minkowski() { cube([size[0] - 2 * r, size[1] - 2 * r, size[2] - 2 * r], center = true); sphere(r = r); }
}""",
    "torus": """// ipm's torus: a ring of radius `major` in the XZ plane, its tube of radius `minor`
module torus(major, minor) { along_y() rotate_extrude() translate([major, 0]) circle(r = minor); }""",
    "hex_prism": """// ipm's hex_prism: a hexagon of inradius `radius` in XZ (corners on X), `height` along Y
module hex_prism(radius, height) { along_y() cylinder(h = height, r = radius / cos(30), center = true, $fn = 6); }""",
    "tri_prism": """// ipm's tri_prism: an equilateral triangle of circumradius `radius` (apex +Y), `length` along Z
module tri_prism(radius, length) {
  linear_extrude(height = length, center = true)
    polygon([[0, radius], [-sin(60) * radius, -radius / 2], [sin(60) * radius, -radius / 2]]);
}""",
    "pyramid": """// ipm's pyramid: a square base of side `base` on y = 0, the apex at y = `height`
module pyramid(base, height) {
  b = base / 2;
  polyhedron(points = [[-b, 0, -b], [b, 0, -b], [b, 0, b], [-b, 0, b], [0, height, 0]],
             faces = [[3, 2, 1, 0], [1, 4, 0], [2, 4, 1], [3, 4, 2], [0, 4, 3]]);  // clockwise seen from outside
}""",
    "octahedron": """// ipm's octahedron: its corners on the axes at `radius`
module octahedron(radius) {
  r = radius;
  polyhedron(points = [[r, 0, 0], [-r, 0, 0], [0, r, 0], [0, -r, 0], [0, 0, r], [0, 0, -r]],
             faces = [[4, 2, 0], [2, 5, 0], [3, 4, 0], [5, 3, 0], [2, 4, 1], [5, 2, 1], [4, 3, 1], [3, 5, 1]]);
}""",
    "revolution": """// ipm's revolution: radii at evenly spaced heights from y = 0 to `height`, turned about Y
module revolution(height, radii) {
  k = len(radii);
  along_y() rotate_extrude()
    polygon(concat([[0, 0]], [for (i = [0 : k - 1]) [radii[i], height * i / (k - 1)]], [[0, height]]));
}""",
    "outline": """// ipm's 2D shell: the band of full width `thickness` around the children's outline
module outline(thickness) {
  difference() { offset(r = thickness / 2) children(); offset(r = -thickness / 2) children(); }
}""",
}

# the modules a module calls
_NEEDS = {"mirror_half": ("half_space",), "revolve": ("along_y",), "torus": ("along_y",), "capsule": ("along_y",),
          "hex_prism": ("along_y",), "revolution": ("along_y",)}


# registers the writer of these node types' statements (calling the helper modules ``uses``)
node = registrar(NODES, USES)


def vec(*vals) -> str:
    """``[a, b, c]`` of program values."""
    return "[" + ", ".join(str(v) for v in vals) + "]"


def unit(axis) -> str:
    """The unit vector of an axis number (0, 1, 2)."""
    return vec(*(int(int(axis.value) == i) for i in range(3)))


def wrap(head: str, kids: list[list[str]]) -> list[str]:
    """``head`` applied to the children: one child on the next line, indented; several in braces."""
    if len(kids) == 1:
        return [head] + ["  " + line for line in kids[0]]
    return [head + " {"] + ["  " + line for k in kids for line in k] + ["}"]


def leaf(text: str) -> Callable:
    """A writer of a childless statement from a template over the part's values (``{radius}``)."""
    return lambda part, kids: [text.format(**part.args) + ";"]


for _kind, _text, _uses in (
    ("sphere", "sphere(r = {radius})", ()),
    ("box", "cube([{size_x}, {size_y}, {size_z}], center = true)", ()),
    ("round_box", "round_box([{size_x}, {size_y}, {size_z}], {radius})", ("round_box",)),
    ("cylinder", "along_y() cylinder(h = {height}, r = {radius}, center = true)", ("along_y",)),
    ("cone", "along_y() cylinder(h = {height}, r1 = {radius_bottom}, r2 = {radius_top}, center = true)",
     ("along_y",)),
    ("capsule", "capsule({radius}, {height})", ("capsule",)),
    ("torus", "torus({major}, {minor})", ("torus",)),
    ("hex_prism", "hex_prism({radius}, {height})", ("hex_prism",)),
    ("tri_prism", "tri_prism({radius}, {length})", ("tri_prism",)),
    ("pyramid", "pyramid({base}, {height})", ("pyramid",)),
    ("octahedron", "octahedron({radius})", ("octahedron",)),
    ("ellipsoid", "scale([{radius_x}, {radius_y}, {radius_z}]) sphere(r = 1)", ()),
    ("plane", "plane({tilt}, {azimuth}, {offset})", ("plane",)),
    ("circle", "circle(r = {radius})", ()),
    ("rect", "square([{size_x}, {size_y}], center = true)", ()),
    ("ellipse", "scale([{radius_x}, {radius_y}]) circle(r = 1)", ()),
    ("triangle", "polygon([[{x0}, {y0}], [{x1}, {y1}], [{x2}, {y2}]])", ()),
):
    node(_kind, uses=_uses)(leaf(_text))


@node("round_rect")
def _round_rect(part: Part, kids) -> list[str]:
    """A rectangle grown back by its corner radius (clamped to half the smaller side, as ipm does)."""
    r = f"min({part['radius']}, min({part['size_x']}, {part['size_y']}) / 2)"
    return [f"offset(r = {r}) square([{part['size_x']} - 2 * {r}, {part['size_y']} - 2 * {r}], center = true);"]


@node("wind_rose")
def _wind_rose(part: Part, kids) -> list[str]:
    """The eight radii on the rays at 0, 45, ..., 315 degrees."""
    pts = ", ".join(f"{part[f'r{i}']} * [cos({45 * i}), sin({45 * i})]" for i in range(8))
    return [f"polygon([{pts}]);"]


@node("polygon")
def _polygon(part: Part, kids) -> list[str]:
    """A closed polygon through its points."""
    return [f"polygon([{', '.join(vec(part[f'x{i}'], part[f'y{i}']) for i in range(part.size))}]);"]


@node("revolution", uses=("revolution",))
def _revolution(part: Part, kids) -> list[str]:
    """The radii as one list."""
    return [f"revolution({part['height']}, {vec(*(part[f'r{i}'] for i in range(part.size)))});"]


node("union", "union_n")(lambda part, kids: wrap("union()", kids))
node("intersection")(lambda part, kids: wrap("intersection()", kids))
node("subtraction")(lambda part, kids: wrap("difference()", kids))
node("translate")(lambda p, kids: wrap(f"translate({vec(p['x'], p['y'], p['z'])})", kids))
node("translate2d")(lambda p, kids: wrap(f"translate({vec(p['x'], p['y'])})", kids))
node("scale", "scale2d")(lambda p, kids: wrap(f"scale({p['factor']})", kids))
node("scale3")(lambda p, kids: wrap(f"scale({vec(p['sx'], p['sy'], p['sz'])})", kids))
node("place")(lambda p, kids: wrap(f"translate({vec(p['x'], p['y'], p['z'])}) scale({p['unit']})", kids))
node("place2d")(lambda p, kids: wrap(f"translate({vec(p['x'], p['y'])}) scale({p['unit']})", kids))
node("rotate", uses=("axis",))(
    lambda p, kids: wrap(f"rotate(a = {p['angle']}, v = axis({p['tilt']}, {p['azimuth']}))", kids))
node("rotate2d")(lambda p, kids: wrap(f"rotate({p['angle']})", kids))
node("mirror", uses=("mirror_half",))(lambda p, kids: wrap(f"mirror_half({unit(p['axis'])}, {p['offset']})", kids))
node("repeat", uses=("repeat",))(
    lambda p, kids: wrap(f"repeat({unit(p['axis'])}, {p['count']}, {p['spacing']})", kids))
node("extrude")(lambda p, kids: wrap(f"linear_extrude(height = {p['height']}, center = true)", kids))
node("revolve", uses=("revolve",))(lambda p, kids: wrap(f"revolve({p['offset']})", kids))
node("round2d")(lambda p, kids: wrap(f"offset(r = {p['radius']})", kids))
node("shell2d", uses=("outline",))(lambda p, kids: wrap(f"outline({p['thickness']})", kids))


def statement(part: Part) -> list[str]:
    """The lines of a part and its children, its note as a comment on its first line."""
    lines = NODES[part.kind](part, [statement(c) for c in part.children])
    return [f"{lines[0]}  // {part.note}" if part.note else lines[0]] + lines[1:]


def modules(program: Program) -> list[str]:
    """The helper modules the program calls, each once, in :data:`MODULES`' order."""
    want = {m for p in walk(program.root) for m in USES[p.kind]}
    want |= {n for m in want for n in _NEEDS.get(m, ())}
    return [MODULES[m] for m in MODULES if m in want]


def write(program: Program, segments: int, header: list[str]) -> str:
    """The whole ``.scad`` file: header, ``$fn``, parameters, helper modules, the shape."""
    used = modules(program)
    lines = [f"// {h}" for h in header] + ["", f"$fn = {segments};  // straight pieces a circle"]
    if any("big" in text for text in used):
        lines.append(f"big = {number(program.big)};  // the side of the cubes that stand for half-spaces")
    lines += ["", "// parameters"]
    for name, val, comment in program.variables:
        lines.append(f"{name} = {bare(val.text)};" + (f"  // {comment}" if comment else ""))
    for text in used:
        lines += ["", text]
    lines += ["", "// the shape"] + statement(program.root)
    return "\n".join(lines) + "\n"


PROGRAMS.add(".scad", ProgramFormat("OpenSCAD", "//", NODES, write))
