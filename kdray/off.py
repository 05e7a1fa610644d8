"""ASCII OFF files, read by kdray itself: their vertices and polygons in file order,
for kdray.load.

trimesh's OFF reader splits a run of quads into every quad's first half, then every
second half (not the file's order), and under numpy 2 refuses a file whose faces mix
triangles with larger polygons. The format (Geomview's): a keyword ending in "OFF"
("OFF", "COFF", "NOFF", "STOFF", ...: colours, normals or texture coordinates after
each vertex's x, y, z), then the vertex, face and edge counts (on the keyword's line
or the next), then a vertex a line and a face a line (its corner count, its corners'
0-based indices, perhaps a colour); "#" starts a comment. Files of another dimension
("4OFF", "nOFF") or binary ones ("OFF BINARY") are left to trimesh.
"""
import numpy as np


class Malformed(ValueError):
    """An ASCII OFF file that kdray reads but whose counts, lines or indices are wrong."""


def read_off(data):
    """(vertices (n, 3) float64, polygons: a list of (k,) int64 index arrays in file
    order) of an ASCII OFF file's bytes. Malformed (a ValueError) for counts, lines or
    indices that are wrong; ValueError (or OverflowError, for a number past int64) for
    a file it does not read: no OFF keyword, another dimension, a binary file."""
    lines = []
    for line in data.decode("ascii", "replace").splitlines():
        words = line.split("#", 1)[0].split()
        if words:
            lines.append(words)
    if not lines or not lines[0][0].endswith("OFF"):
        raise ValueError("no OFF keyword")
    keyword = lines[0][0]
    if "4" in keyword or "n" in keyword or (len(lines[0]) > 1 and lines[0][1] == "BINARY"):
        raise ValueError(f"an OFF file kdray does not read ({' '.join(lines[0])})")
    if len(lines[0]) == 1 and len(lines) < 2:
        raise Malformed("no vertex and face counts")
    head, at = (lines[0][1:], 1) if len(lines[0]) > 1 else (lines[1], 2)
    if len(head) < 2:
        raise Malformed("no vertex and face counts")
    n_vertices, n_faces = int(head[0]), int(head[1])
    if n_vertices < 0 or n_faces < 0 or at + n_vertices + n_faces > len(lines):
        raise Malformed("the file ends before its counts of vertices and faces (kdray "
                        "reads a vertex a line and a face a line)")
    vertices = np.array([words[:3] for words in lines[at:at + n_vertices]], dtype=np.float64)
    if vertices.shape != (n_vertices, 3):
        raise Malformed("a vertex line with fewer than 3 numbers")
    polygons = []
    for words in lines[at + n_vertices:at + n_vertices + n_faces]:
        k = int(words[0])
        if k < 0 or len(words) < k + 1:
            raise Malformed(f"a face line with fewer corners than its count: {' '.join(words)}")
        corners = np.array(words[1:k + 1], dtype=np.int64)
        if k and (corners.min() < 0 or corners.max() >= n_vertices):
            raise Malformed(f"a face refers to a vertex that does not exist: {' '.join(words)}")
        polygons.append(corners)
    return vertices, polygons
