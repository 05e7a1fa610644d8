"""Write the small scenes kdray ships (deterministic; plain Python, no dependencies).

    python scenes/make_scenes.py           # (re)write the files next to this script
    python scenes/make_scenes.py --check   # exit 1 if a committed file differs

Outputs (see README.md):

    cornell.obj   a Cornell-box-like room, open at the front (+z); y up; quads
    cornell.json  a kdray camera file: the classic straight-on view of cornell.obj
    sphere.obj    a closed unit icosphere: 642 shared vertices, 1280 triangles
    quads.obj     a closed "house" prism of quads with two pentagon ends

Every face is wound counter-clockwise seen from the side its normal points to
(kdray's normal is (v1 - v0) x (v2 - v0)): room walls face into the room, closed
meshes face outwards. Coordinates are written with 6 decimals, so the bytes do not
depend on the platform's maths library.
"""
import json
import math
import sys
from pathlib import Path

HERE = Path(__file__).resolve().parent


# Small vector helpers ---------------------------------------------------------------


def add(a, b):
    return tuple(x + y for x, y in zip(a, b))


def sub(a, b):
    return tuple(x - y for x, y in zip(a, b))


def scale(a, s):
    return tuple(x * s for x in a)


def dot(a, b):
    return sum(x * y for x, y in zip(a, b))


def cross(a, b):
    return (a[1] * b[2] - a[2] * b[1], a[2] * b[0] - a[0] * b[2], a[0] * b[1] - a[1] * b[0])


def normalize(a):
    return scale(a, 1.0 / math.sqrt(dot(a, a)))


def centroid(points):
    return scale(tuple(map(sum, zip(*points))), 1.0 / len(points))


def newell_normal(points):
    """Area-weighted normal of a planar polygon, from its winding."""
    n = (0.0, 0.0, 0.0)
    for i, p in enumerate(points):
        n = add(n, cross(p, points[(i + 1) % len(points)]))
    return n


def facing(points, toward):
    """`points` wound so that its normal points towards the point `toward`."""
    n = newell_normal(points)
    side = dot(n, sub(toward, centroid(points)))
    assert side != 0, "polygon plane passes through the reference point"
    return list(points) if side > 0 else list(reversed(points))


def facing_away(points, away):
    return list(reversed(facing(points, away)))


# OBJ writing ------------------------------------------------------------------------


def number(x):
    text = f"{x:.6f}".rstrip("0").rstrip(".")
    return "0" if text in ("-0", "") else text


class Obj:
    """Polygons with shared vertices, in the order added."""

    def __init__(self):
        self.vertices = []
        self.index = {}
        self.faces = []  # (comment or None, [vertex indices])

    def vertex(self, p):
        key = tuple(number(x) for x in p)
        if key not in self.index:
            self.index[key] = len(self.vertices)
            self.vertices.append(key)
        return self.index[key]

    def face(self, points, comment=None):
        self.faces.append((comment, [self.vertex(p) for p in points]))

    def text(self, header):
        lines = [f"# {line}" if line else "#" for line in header.splitlines()]
        lines.append(f"# {len(self.vertices)} vertices, {len(self.faces)} faces")
        lines += ["v " + " ".join(v) for v in self.vertices]
        for comment, face in self.faces:
            if comment:
                lines.append(f"# {comment}")
            lines.append("f " + " ".join(str(i + 1) for i in face))
        return "\n".join(lines) + "\n"


# cornell.obj ------------------------------------------------------------------------

ROOM_MIN = (-0.5, 0.0, -0.5)
ROOM_MAX = (0.5, 1.0, 0.5)


def box_around_y(obj, name, centre_xz, half, height, degrees):
    """A box standing on the floor, turned `degrees` about y: 4 sides and a top,
    facing outwards (no bottom: it would coincide with the floor)."""
    a = math.radians(degrees)
    c, s = math.cos(a), math.sin(a)
    foot = []
    for lx, lz in ((-half, -half), (half, -half), (half, half), (-half, half)):
        foot.append((centre_xz[0] + c * lx + s * lz, centre_xz[1] - s * lx + c * lz))
    inside = (centre_xz[0], height / 2.0, centre_xz[1])
    for i in range(4):
        (x0, z0), (x1, z1) = foot[i], foot[(i + 1) % 4]
        side = [(x0, 0.0, z0), (x1, 0.0, z1), (x1, height, z1), (x0, height, z0)]
        obj.face(facing_away(side, inside), f"{name}: side {i}")
    top = [(x, height, z) for x, z in foot]
    obj.face(facing_away(top, inside), f"{name}: top")


def cornell():
    obj = Obj()
    (x0, y0, z0), (x1, y1, z1) = ROOM_MIN, ROOM_MAX
    inside = centroid([ROOM_MIN, ROOM_MAX])
    walls = {
        "floor": [(x0, y0, z0), (x1, y0, z0), (x1, y0, z1), (x0, y0, z1)],
        "ceiling": [(x0, y1, z0), (x1, y1, z0), (x1, y1, z1), (x0, y1, z1)],
        "back wall": [(x0, y0, z0), (x1, y0, z0), (x1, y1, z0), (x0, y1, z0)],
        "left wall": [(x0, y0, z0), (x0, y0, z1), (x0, y1, z1), (x0, y1, z0)],
        "right wall": [(x1, y0, z0), (x1, y0, z1), (x1, y1, z1), (x1, y1, z0)],
    }
    for name, quad in walls.items():
        obj.face(facing(quad, inside), name)
    # The light: a small quad just below the ceiling (not coplanar with it), facing down.
    ly, hx, hz = y1 - 0.002, 0.12, 0.095
    light = [(-hx, ly, -hz), (hx, ly, -hz), (hx, ly, hz), (-hx, ly, hz)]
    obj.face(facing(light, (0.0, 0.0, 0.0)), "light")
    box_around_y(obj, "tall box", (-0.18, -0.14), 0.15, 0.6, 17.0)
    box_around_y(obj, "short box", (0.18, 0.12), 0.15, 0.3, -17.0)
    header = (
        "cornell.obj: a Cornell-box-like room for kdray (scenes/make_scenes.py).\n"
        "y up; room x, z in [-0.5, 0.5], y in [0, 1]; open at the front (+z).\n"
        "Walls face into the room; the two boxes face outwards."
    )
    return obj.text(header)


CORNELL_CAMERA = {
    "width": 640,
    "height": 480,
    "eye": [0.0, 0.5, 1.85],
    "target": [0.0, 0.5, 0.0],
    "up": [0.0, 1.0, 0.0],
    "fov": 40.0,
}


# sphere.obj -------------------------------------------------------------------------


def icosphere(subdivisions=3):
    """Unit icosphere: an icosahedron whose triangles are split in four `subdivisions`
    times, new vertices pushed onto the sphere. Returns (vertices, triangles)."""
    t = (1.0 + math.sqrt(5.0)) / 2.0
    vertices = [
        normalize(p)
        for p in [
            (-1, t, 0), (1, t, 0), (-1, -t, 0), (1, -t, 0),
            (0, -1, t), (0, 1, t), (0, -1, -t), (0, 1, -t),
            (t, 0, -1), (t, 0, 1), (-t, 0, -1), (-t, 0, 1),
        ]
    ]
    triangles = [
        (0, 11, 5), (0, 5, 1), (0, 1, 7), (0, 7, 10), (0, 10, 11),
        (1, 5, 9), (5, 11, 4), (11, 10, 2), (10, 7, 6), (7, 1, 8),
        (3, 9, 4), (3, 4, 2), (3, 2, 6), (3, 6, 8), (3, 8, 9),
        (4, 9, 5), (2, 4, 11), (6, 2, 10), (8, 6, 7), (9, 8, 1),
    ]
    for _ in range(subdivisions):
        midpoints = {}

        def midpoint(i, j):
            key = (min(i, j), max(i, j))
            if key not in midpoints:
                midpoints[key] = len(vertices)
                vertices.append(normalize(scale(add(vertices[i], vertices[j]), 0.5)))
            return midpoints[key]

        finer = []
        for a, b, c in triangles:
            ab, bc, ca = midpoint(a, b), midpoint(b, c), midpoint(c, a)
            finer += [(a, ab, ca), (b, bc, ab), (c, ca, bc), (ab, bc, ca)]
        triangles = finer
    return vertices, triangles


def sphere():
    vertices, triangles = icosphere(3)
    obj = Obj()
    for a, b, c in triangles:
        tri = [vertices[a], vertices[b], vertices[c]]
        assert dot(newell_normal(tri), centroid(tri)) > 0, "icosphere face wound inwards"
        obj.face(tri)
    assert len(obj.vertices) == len(vertices) == 642 and len(obj.faces) == 1280
    header = (
        "sphere.obj: a closed unit icosphere for kdray (scenes/make_scenes.py).\n"
        "An icosahedron subdivided 3 times: 642 shared vertices, 1280 triangles, facing out."
    )
    return obj.text(header)


# quads.obj --------------------------------------------------------------------------

HOUSE_PROFILE = [(-0.5, 0.0), (0.5, 0.0), (0.5, 0.6), (0.0, 1.0), (-0.5, 0.6)]
"""The house's end: a convex pentagon in x, y (counter-clockwise seen from +z)."""
HOUSE_RINGS = (-0.75, -0.25, 0.25, 0.75)
"""z of each copy of the profile: the sides are 3 quads long."""


def quads():
    obj = Obj()
    inside = (0.0, 0.45, 0.0)
    rings = [[(x, y, z) for x, y in HOUSE_PROFILE] for z in HOUSE_RINGS]
    names = ("floor", "right wall", "right roof", "left roof", "left wall")
    for i, name in enumerate(names):
        j = (i + 1) % len(HOUSE_PROFILE)
        for k in range(len(rings) - 1):
            quad = [rings[k][i], rings[k][j], rings[k + 1][j], rings[k + 1][i]]
            obj.face(facing_away(quad, inside), f"{name} {k}")
    obj.face(facing_away(rings[-1], inside), "front end (pentagon)")
    obj.face(facing_away(rings[0], inside), "back end (pentagon)")
    header = (
        "quads.obj: a closed house-shaped prism for kdray (scenes/make_scenes.py).\n"
        "15 quads and 2 pentagons (convex), facing out: for testing triangulation."
    )
    return obj.text(header)


# Main -------------------------------------------------------------------------------


def outputs():
    return {
        "cornell.obj": cornell(),
        "cornell.json": json.dumps(CORNELL_CAMERA, indent=2) + "\n",
        "sphere.obj": sphere(),
        "quads.obj": quads(),
    }


def main(argv):
    check = "--check" in argv
    stale = []
    for name, text in outputs().items():
        path = HERE / name
        if check:
            if not path.exists() or path.read_text() != text:
                stale.append(name)
        else:
            path.write_text(text)
    if stale:
        print(f"out of date: {', '.join(stale)} (run python scenes/make_scenes.py)", file=sys.stderr)
        return 1
    return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
