"""Loading meshes: formats, triangulation, scenes, and clear errors."""
import numpy as np
import pytest

from kdray.load import load
from kdray.errors import MeshError
from kdray.mesh import Mesh
from helpers import real_mesh


@pytest.mark.parametrize("name, n_tris", [("stanford-bunny.obj", 69451), ("fandisk.obj", 12946),
                                          ("teapot.obj", 6320), ("spot.obj", 5856)])
def test_real_meshes(name, n_tris):
    m = load(real_mesh(name))
    assert m.faces.shape == (n_tris, 3) and m.vertices.dtype == np.float64
    assert m.faces.min() >= 0 and m.faces.max() < len(m.vertices)
    assert m.object_names == (name,) and m.objects.shape == (n_tris,) and not m.objects.any()


def test_gzipped_files_read_as_their_format(tmp_path):
    """NAME.obj.gz loads as NAME.obj would, under that name; a .gz whose inner name has
    an unknown extension is refused."""
    from helpers import MESHES
    zipped, plain = load(MESHES / "spot.obj.gz"), load(real_mesh("spot.obj"))
    assert zipped.name == plain.name == "spot.obj"
    assert np.array_equal(zipped.vertices, plain.vertices) and np.array_equal(zipped.faces, plain.faces)
    odd = tmp_path / "mesh.abc.gz"
    odd.write_bytes((MESHES / "spot.obj.gz").read_bytes())
    with pytest.raises(MeshError, match="unknown mesh format .abc"):
        load(odd)


def test_quads_and_polygons_are_triangulated(tmp_path):
    p = tmp_path / "q.obj"
    p.write_text("v 0 0 0\nv 1 0 0\nv 1 1 0\nv 0 1 0\nv 2 0 0\nv 2 1 0\nv 1.5 2 0\n"
                 "f 1 2 3 4\nf 2 5 6 7 3\nusemtl nothing\n")
    m = load(p)
    assert len(m.faces) == 2 + 3
    assert np.isclose(np.linalg.norm(np.cross(m.triangles[:, 1] - m.triangles[:, 0],
                                              m.triangles[:, 2] - m.triangles[:, 0]), axis=1).sum() / 2,
                      1 + 1 + 0.5)


def test_ply_and_stl(tmp_path):
    import trimesh
    box = trimesh.creation.box()
    for ext in ("ply", "stl", "off"):
        p = tmp_path / f"box.{ext}"
        box.export(p)
        assert len(load(p).faces) == 12


def test_scene_transforms_are_applied(tmp_path):
    import trimesh
    a = trimesh.creation.box()
    scene = trimesh.Scene()
    scene.add_geometry(a, node_name="a")
    scene.add_geometry(a, node_name="b", transform=trimesh.transformations.translation_matrix([10, 0, 0]))
    p = tmp_path / "s.glb"
    scene.export(p)
    m = load(p)
    assert len(m.faces) == 24
    assert m.bounds[1][0] == pytest.approx(10.5)
    assert sorted(m.object_names) == ["a", "b"] and np.bincount(m.objects).tolist() == [12, 12]
    b = m.objects == m.object_names.index("b")                 # the translated node
    assert np.all(m.triangles[b][..., 0] > 9) and np.all(m.triangles[~b][..., 0] < 1)


def test_mirrored_and_nearly_identity_transforms(tmp_path):
    """A node whose transform mirrors (a negative determinant) turns its triangles'
    winding, as glTF 2.0 and trimesh's dump have it, so normals stay outward; a
    transform however near the identity is applied."""
    import trimesh
    box = trimesh.creation.box()
    scene = trimesh.Scene()
    scene.add_geometry(box, node_name="plain")
    scene.add_geometry(box, node_name="mirrored", transform=np.diag([1.0, 1.0, -1.0, 1.0])
                       @ trimesh.transformations.translation_matrix([3, 0, 0]))
    near = trimesh.transformations.scale_matrix(1 + 5e-6)
    near[:3, 3] = [2e6 * 5e-6, 0, 0]
    scene.add_geometry(box.copy().apply_translation([2e6, 0, 0]), node_name="near",
                       transform=near)
    p = tmp_path / "s.glb"
    scene.export(p)
    m = load(p)
    want = trimesh.load(p, force="scene").to_geometry()
    for name in ("plain", "mirrored"):
        t = m.triangles[m.objects == m.object_names.index(name)]
        centre = t.reshape(-1, 3).mean(axis=0)
        n = np.cross(t[:, 1] - t[:, 0], t[:, 2] - t[:, 0])
        assert ((n * (t.mean(axis=1) - centre)).sum(axis=1) > 0).all(), name   # outward
    assert m.bounds[1][0] == want.bounds[1][0] and m.bounds[1][0] > 2e6 + 10


def test_obj_relative_indices_count_back_from_their_line(tmp_path):
    """OBJ's negative indices count back from the last vertex (texture coordinate,
    normal) read before their line, not from the file's last."""
    p = tmp_path / "r.obj"
    p.write_text("v 0 0 0\nv 1 0 0\nv 0 1 0\nvt 0 0\nvt 1 0\nvt 0 1\n"
                 "o first\nf -3/-3 -2/-2 -1/-1\n"
                 "v 0 0 7\nv 1 0 7\nv 0 1 7\n  f  4 5 -1\r\n"
                 "o second\nv 0 0 -2\nv 2 0 -2\nv 0 2 -2\nf -3 -2 -1\n")
    m = load(p)
    assert m.triangles[:, :, 2].tolist() == [[0, 0, 0], [7, 7, 7], [-2, -2, -2]]
    assert m.object_names == ("first", "second") and m.objects.tolist() == [0, 0, 1]
    continued = tmp_path / "c.obj"              # a face line continued by a backslash
    continued.write_text("v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 \\\n -1\nv 9 9 9\n")
    assert load(continued).triangles[0].tolist() == [[0, 0, 0], [1, 0, 0], [0, 1, 0]]
    q = tmp_path / "plain.obj"                   # the same file with absolute indices
    q.write_text("v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 3\nv 0 0 7\nv 1 0 7\nv 0 1 7\nf 4 5 6\n"
                 "v 0 0 -2\nv 2 0 -2\nv 0 2 -2\nf 7 8 9\n")
    np.testing.assert_array_equal(load(q).triangles, m.triangles)


def test_obj_indices_that_name_no_vertex_are_refused(tmp_path):
    """An index 0 (OBJ counts from 1) or one counting back past the first vertex names
    no vertex: refused with the line, not read as some other vertex (trimesh reads 0 as
    the last one). Other keywords' zeros (lod 0, parm u 0 1) are no indices."""
    head = "v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 3\n"
    for face, words in (("f 1 2 0", "line 5 holds the index 0"),
                        ("f 1/1 2/0 3/1", "line 5 holds the index 0"),
                        ("l 1 -0", "line 5 holds the index 0"),
                        ("f 1 2 -4", "line 5: -4 counts back past the first of 3"),
                        ("f -9 2 3", "line 5: -9 counts back")):
        p = tmp_path / "z.obj"
        p.write_text(head + face + "\n")
        with pytest.raises(MeshError, match=f"vertex that does not exist .*{words}"):
            load(p)
    p.write_text("v 0 0 0\nv 1 0 0\nv 0 1 0\nlod 0\nparm u 0 1\nf 3 -3 2\n")
    assert load(p).faces.tolist() == [[2, 0, 1]]


def test_obj_lines_trimesh_would_drop(tmp_path):
    """OBJ lines trimesh leaves out or refuses are read as the format has them: an
    indented line, "f" or "v" and a tab, a comment after a line's numbers; a "#" in an
    object's name stays in it."""
    p = tmp_path / "ragged.obj"
    p.write_text("v 0 0 0\nv\t1 0 0\n  v 0 1 0   # the third\nv 0 0 1\n"
                 "f 1 2 3 # a comment\no part#1\n\tf\t1\t2\t4\n   f 1 3 4\n")
    m = load(p)
    v = np.array([[0, 0, 0], [1, 0, 0], [0, 1, 0], [0, 0, 1]], np.float64)
    np.testing.assert_array_equal(m.triangles, v[[[0, 1, 2], [0, 1, 3], [0, 2, 3]]])
    assert m.object_names == ("ragged.obj", "part#1") and m.objects.tolist() == [0, 1, 1]


def test_off_polygons_in_file_order(tmp_path):
    """An OFF file's polygons become triangles in the file's order (a quad's two in
    turn, where trimesh's reader puts every first half, then every second half),
    triangles mixed with larger polygons too (trimesh's refuses them under numpy 2),
    with comments, colours and the counts on the keyword's line; gzipped the same. A
    face with an index out of range is a MeshError."""
    import gzip
    v = [[0, 0, 0], [1, 0, 0], [1, 1, 0], [0, 1, 0], [0, 0, 1], [1, 0, 1], [2, 0, 0]]
    faces = [[0, 1, 2, 3], [1, 2, 5], [0, 1, 5, 4], [0, 1, 6, 2, 3], [4, 5, 1]]
    want = [[0, 1, 2], [2, 3, 0], [1, 2, 5], [0, 1, 5], [5, 4, 0],
            [0, 1, 6], [0, 6, 2], [0, 2, 3], [4, 5, 1]]
    text = ("COFF  # colours after each vertex\n# a comment line\n\n7 5 0\n"
            + "".join(f"{x} {y} {z} 255 0 0 255\n" for x, y, z in v)
            + "".join(" ".join(map(str, [len(f)] + f)) + " 0.5 0.5 0.5\n" for f in faces))
    off = tmp_path / "p.off"
    off.write_text(text)
    assert load(off).faces.tolist() == want
    np.testing.assert_array_equal(load(off).vertices, np.array(v, np.float64))
    one_line = tmp_path / "q.off"                   # the counts on the keyword's line
    one_line.write_text("OFF 7 2 0\n" + "".join(f"{x} {y} {z}\n" for x, y, z in v)
                        + "4 0 1 2 3\n4 0 1 5 4\n")
    assert load(one_line).faces.tolist() == [[0, 1, 2], [2, 3, 0], [0, 1, 5], [5, 4, 0]]
    zipped = tmp_path / "p.off.gz"
    zipped.write_bytes(gzip.compress(text.encode()))
    assert load(zipped).faces.tolist() == want
    bad = tmp_path / "bad.off"
    bad.write_text("OFF\n3 1 0\n0 0 0\n1 0 0\n0 1 0\n3 0 1 7\n")
    with pytest.raises(MeshError):
        load(bad)


def test_ply_polygons_in_file_order(tmp_path):
    """A PLY file's polygons become triangles in the file's order (a quad's two, then
    the next face's), split as trimesh splits them, in ASCII and binary."""
    import struct
    v = np.array([[0, 0, 0], [1, 0, 0], [1, 1, 0], [0, 1, 0], [0, 0, 1], [1, 0, 1],
                  [2, 0, 0]], dtype=np.float32)
    faces = [[0, 1, 2, 3], [1, 2, 5], [0, 1, 5, 4], [0, 1, 6, 2, 3]]
    want = [[0, 1, 2], [2, 3, 0], [1, 2, 5], [0, 1, 5], [5, 4, 0],
            [0, 1, 6], [0, 6, 2], [0, 2, 3]]
    head = ("ply\nformat {}\nelement vertex 7\nproperty float x\nproperty float y\n"
            "property float z\nelement face {}\nproperty list uchar int vertex_indices\n"
            "end_header\n")
    ascii_ply = tmp_path / "a.ply"
    ascii_ply.write_text(head.format("ascii 1.0", len(faces))
                         + "".join("%g %g %g\n" % tuple(p) for p in v)
                         + "".join(" ".join(map(str, [len(f)] + f)) + "\n" for f in faces))
    assert load(ascii_ply).faces.tolist() == want
    quads = [faces[0], faces[2]]                 # binary: trimesh reads one length only
    binary_ply = tmp_path / "b.ply"
    binary_ply.write_bytes(head.format("binary_little_endian 1.0", 2).encode() + v.tobytes()
                           + b"".join(struct.pack("<B4i", 4, *f) for f in quads))
    assert load(binary_ply).faces.tolist() == [want[0], want[1], want[3], want[4]]


def test_obj_quads_in_file_order(tmp_path):
    """An OBJ file's quads become triangles in the file's order, each quad's two in
    turn, as a PLY's do (trimesh split a run of quad lines into every first half, then
    every second half); a file of triangles keeps its order however its triangles
    pair up, and o/g groups follow their triangles."""
    v = "".join(f"v {x} {y} {z}\n" for x, y, z in
                [(0, 0, 0), (1, 0, 0), (1, 1, 0), (0, 1, 0), (2, 0, 0), (3, 0, 0), (3, 1, 0),
                 (2, 1, 0), (0, 0, 1), (1, 0, 1), (1, 1, 1), (0, 1, 1)])
    quads = tmp_path / "quads.obj"
    quads.write_text(v + "o a\nf 1 2 3 4\nf 5/1 6/1 7/1 8/1\no b\nf 9 10 11 12\n")
    m = load(quads)
    assert m.faces.tolist() == [[0, 1, 2], [2, 3, 0], [4, 5, 6], [6, 7, 4],
                                [8, 9, 10], [10, 11, 8]]
    assert m.object_names == ("a", "b") and m.objects.tolist() == [0, 0, 0, 0, 1, 1]
    one = tmp_path / "one.obj"                     # one run of quads, no groups
    one.write_text(v + "f 1 2 3 4\nf 5 6 7 8\nf 9 10 11 12\n")
    assert load(one).faces.tolist() == [[0, 1, 2], [2, 3, 0], [4, 5, 6], [6, 7, 4],
                                        [8, 9, 10], [10, 11, 8]]
    # the same triangles written in trimesh's order (first halves, then second halves)
    # by a tool: a file of triangles, kept as it is
    halves = tmp_path / "halves.obj"
    halves.write_text(v + "f 1 2 3\nf 5 6 7\nf 9 10 11\nf 3 4 1\nf 7 8 5\nf 11 12 9\n")
    assert load(halves).faces.tolist() == [[0, 1, 2], [4, 5, 6], [8, 9, 10], [2, 3, 0],
                                           [6, 7, 4], [10, 11, 8]]
    # triangles that pair up as trimesh's halves would, and one quad line: the file's
    # order all the same (a guess from the halves' shared corners took them for quads)
    pattern = tmp_path / "pattern.obj"
    pattern.write_text(v + "f 1 2 3\nf 4 5 6\nf 6 7 4\nf 3 8 1\nf 6 9 4 10\n")
    want = [[0, 1, 2], [3, 4, 5], [5, 6, 3], [2, 7, 0], [5, 8, 3], [3, 9, 5]]
    np.testing.assert_array_equal(load(pattern).triangles, m.vertices[want])
    mixed = tmp_path / "mixed.obj"       # sizes mixed: in turn already (vertices renumbered)
    mixed.write_text(v + "f 1 2 3 4\nf 5 6 7\nf 9 10 11 12 4\n")
    want = m.vertices[[[0, 1, 2], [2, 3, 0], [4, 5, 6], [8, 9, 10], [8, 10, 11], [8, 11, 3]]]
    np.testing.assert_array_equal(load(mixed).triangles, want)


def obj_of_materials(rng, n_faces, form):
    """An OBJ's text of n_faces polygons of 3 to 6 corners (random coordinates, some
    vertices shared), a `usemtl` of 3 materials switched every few faces, face words of
    `form` ("v", "v/vt", "v//vn", "v/vt/vn", or "mixed": each word its own), comments
    and a line continued by a backslash; and the triangles it holds in file order:
    (text, (m, 3, 3) float64), each polygon split as trimesh splits it (a quad into
    (0, 1, 2), (2, 3, 0), larger ones into fans), written here from the polygons."""
    v = rng.normal(size=(2 * n_faces + 6, 3)).round(7)
    lines = ["# made for a test", "mtllib none.mtl"]
    lines += [f"v {x!r} {y!r} {z!r}" for x, y, z in v.tolist()]
    lines += ["vt 0.5 0.5", "vn 0 0 1"]
    want = []
    forms = ["{}", "{}/1", "{}//1", "{}/1/1"]
    for j in range(n_faces):
        if j % 3 == 0:
            lines.append(f"usemtl m{rng.integers(3)}")
        k = int(rng.integers(3, 7))
        corners = rng.choice(len(v), size=k, replace=False)
        words = []
        for c in corners:
            f = forms[rng.integers(4)] if form == "mixed" else forms[["v", "v/vt", "v//vn", "v/vt/vn"].index(form)]
            words.append(f.format(c + 1))
        line = "f " + " ".join(words)
        if j == 5:
            line = line.replace(" ", " \\\n", 1)          # continued on the next line
        if j == 7:
            lines.append("# a comment between faces")
        lines.append(line)
        split = [[0, 1, 2], [2, 3, 0]] if k == 4 else [[0, i, i + 1] for i in range(1, k - 1)]
        want += [v[corners[t]] for t in split]
    return "\n".join(lines) + "\n", np.array(want)


@pytest.mark.parametrize("form", ["v", "v/vt", "v//vn", "v/vt/vn", "mixed"])
def test_obj_of_several_materials_in_file_order(tmp_path, form, caplog):
    """trimesh makes a mesh of each material of an OBJ, in an order of its own: the
    triangles are put back in the file's order, whatever the face lines' form, with
    polygons, comments and continued lines, and its o/g groups follow them."""
    rng = np.random.default_rng(["v", "v/vt", "v//vn", "v/vt/vn", "mixed"].index(form))
    text, want = obj_of_materials(rng, 40, form)
    p = tmp_path / "m.obj"
    p.write_text(text)
    m = load(p)
    np.testing.assert_array_equal(m.triangles, want)
    assert "file's order" not in caplog.text
    grouped = tmp_path / "g.obj"                 # o/g groups: objects follow the triangles
    lines = text.split("\n")
    first_face = next(i for i, line in enumerate(lines) if line.startswith("f "))
    lines.insert(first_face, "o first")
    lines.insert(len(lines) - 10, "o second")
    grouped.write_text("\n".join(lines))
    g = load(grouped)
    np.testing.assert_array_equal(g.triangles, want)
    second = sum(line.startswith("f ") for line in lines[lines.index("o second"):])
    n_second = sum(len(line.split()) - 3 for line in lines[lines.index("o second"):]
                   if line.startswith("f "))
    assert g.object_names == ("first", "second") and second > 0
    assert g.objects.tolist() == [0] * (len(want) - n_second) + [1] * n_second


def test_obj_materials_order_left_with_a_warning(tmp_path, monkeypatch, caplog):
    """Where kdray's own read of the face lines gives other triangles than trimesh's,
    the triangles stay in trimesh's order (each material's faces in file order) and a
    warning says so."""
    import sys
    load_module = sys.modules["kdray.load"]
    text, want = obj_of_materials(np.random.default_rng(9), 12, "v")
    p = tmp_path / "m.obj"
    p.write_text(text)
    monkeypatch.setattr(load_module, "_obj_file_triangles", lambda data: want[::-1] + 1.0)
    m = load(p)
    assert "cannot put its triangles in the file's order" in caplog.text
    assert len(m.faces) == len(want) and not np.array_equal(m.triangles, want)
    assert {t.tobytes() for t in m.triangles} == {t.tobytes() for t in want}


@pytest.mark.parametrize("endian", ["<", ">"])
def test_binary_ply_of_polygons_of_several_sizes(tmp_path, endian):
    """A binary PLY whose faces are of several sizes (trimesh's reader refuses it) loads
    as its ASCII twin does: other vertex and face properties and other elements read
    past; a file cut short is a one-line MeshError."""
    import struct
    v = [[0, 0, 0], [1, 0, 0], [1, 1, 0], [0, 1, 0], [0, 0, 1], [1, 0, 1], [2, 0, 0]]
    faces = [[1, 2, 5], [0, 1, 2, 3], [0, 1, 6, 2, 3], [4, 5, 1]]
    fmt = "binary_little_endian" if endian == "<" else "binary_big_endian"
    head = ("ply\nformat {}\ncomment made by a test\nelement vertex 7\nproperty float x\n"
            "property double y\nproperty float z\nproperty uchar red\nelement face 4\n"
            "property list uchar int vertex_indices\nproperty ushort flags\n"
            "element edge 1\nproperty list uchar uint vertex_index\nend_header\n")
    body = b"".join(struct.pack(endian + "fdfB", x, y, z, 7) for x, y, z in v)
    body += b"".join(struct.pack(f"{endian}B{len(f)}iH", len(f), *f, 3) for f in faces)
    body += struct.pack(endian + "B2I", 2, 0, 1)
    binary = tmp_path / "b.ply"
    binary.write_bytes(head.format(fmt).encode() + body)
    text = tmp_path / "a.ply"
    text.write_text(head.format("ascii 1.0") + "".join(f"{x} {y} {z} 7\n" for x, y, z in v)
                    + "".join(" ".join(map(str, [len(f)] + f + [3])) + "\n" for f in faces)
                    + "2 0 1\n")
    got, want = load(binary), load(text)
    assert got.faces.tolist() == want.faces.tolist() == [
        [1, 2, 5], [0, 1, 2], [2, 3, 0], [0, 1, 6], [0, 6, 2], [0, 2, 3], [4, 5, 1]]
    np.testing.assert_array_equal(got.vertices, want.vertices)
    binary.write_bytes(head.format(fmt).encode() + body[:-30])
    with pytest.raises(MeshError, match="cannot be read as a mesh"):
        load(binary)
    # headers whose counts or properties are cut or absurd (found by the long fuzz):
    # a one-line MeshError, never an IndexError or OverflowError
    for old, new in [("element vertex 7", "element vertex"),
                     ("element vertex 7", "element vertex 99999999999999999999"),
                     ("element face 4", "element face"),
                     ("property float z", "property float"),
                     ("property list uchar int vertex_indices", "property list uchar int"),
                     ("element vertex 7", "element vertex 70000"),
                     ("format {}".format(fmt), "format")]:
        binary.write_bytes(head.format(fmt).replace(old, new).encode() + body)
        with pytest.raises(MeshError, match="cannot be read as a mesh"):
            load(binary)


@pytest.mark.parametrize("content, ext, message", [
    (None, "obj", "no such file"),
    ("", "obj", "empty"),
    ("hello", "qqq", "unknown mesh format"),
    ("v 0 0 0\nv 1 0 0\n", "obj", "no triangles"),
    ("ply\nformat ascii 1.0\nelement vertex 2\nproperty float x\nproperty float y\nproperty float z\n"
     "end_header\n0 0 0\n1 1 1\n", "ply", "no triangles"),
    ("v 0 0 0\nv 1 0 0\nv nan 1 0\nf 1 2 3\n", "obj", "not finite"),
    ("v 0 0 0\nv 1 0 0\nv inf 1 0\nf 1 2 3\n", "obj", "not finite"),
])
def test_bad_files(tmp_path, content, ext, message):
    p = tmp_path / f"m.{ext}"
    if content is not None:
        p.write_text(content)
    with pytest.raises(MeshError, match=message):
        load(p)


def test_mesh_arrays_are_checked():
    with pytest.raises(MeshError, match="out of range"):
        Mesh.from_arrays(np.zeros((3, 3)), [[0, 1, 3]])
    with pytest.raises(MeshError, match="no triangles"):
        Mesh.from_arrays(np.zeros((3, 3)), np.zeros((0, 3), int))
    with pytest.raises(MeshError, match=r"\(m, 3\)"):
        Mesh.from_arrays(np.zeros((4, 3)), [[0, 1, 2, 3]])


def test_non_mesh_and_unreadable_files(tmp_path, monkeypatch):
    junk = tmp_path / "junk.ply"
    junk.write_bytes(bytes(np.random.default_rng(0).integers(0, 256, 4096).astype(np.uint8)))
    with pytest.raises(MeshError, match="junk.ply"):
        load(junk)
    text = tmp_path / "notes.obj"
    text.write_text("this is not a mesh\njust words\n")
    with pytest.raises(MeshError, match="notes.obj.*no triangles"):
        load(text)
    png = tmp_path / "image.stl"
    png.write_bytes(b"\x89PNG\r\n\x1a\n" + bytes(200))
    with pytest.raises(MeshError, match="image.stl"):
        load(png)
    with pytest.raises(MeshError, match="is a folder"):
        load(tmp_path)
    import os
    secret = tmp_path / "secret.obj"
    secret.write_text("v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 3\n")
    real_access = os.access                     # root reads anything: pretend otherwise
    monkeypatch.setattr(os, "access", lambda p, m: False if str(p) == str(secret) else real_access(p, m))
    with pytest.raises(MeshError, match="permission denied"):
        load(secret)


def test_text_files_with_a_bom_or_bytes_not_utf8(tmp_path):
    """A UTF-8 byte-order mark does not cost an OBJ its first vertex, and a comment in
    another encoding (a Latin-1 byte) does not make an OBJ, ASCII STL or ASCII PLY
    unreadable (trimesh would ask an optional module to guess the encoding)."""
    bom = tmp_path / "bom.obj"
    bom.write_bytes(b"\xef\xbb\xbfv 5 5 5\nv 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 3\n")
    assert load(bom).triangles.tolist() == [[[5, 5, 5], [0, 0, 0], [1, 0, 0]]]
    files = {
        "obj": b"# caf\xe9\nv 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 3\n",
        "stl": (b"solid caf\xe9\nfacet normal 0 0 1\nouter loop\nvertex 0 0 0\nvertex 1 0 0\n"
                b"vertex 0 1 0\nendloop\nendfacet\nendsolid caf\xe9\n"),
        "ply": (b"ply\nformat ascii 1.0\ncomment caf\xe9\nelement vertex 3\nproperty float x\n"
                b"property float y\nproperty float z\nelement face 1\n"
                b"property list uchar int vertex_indices\nend_header\n0 0 0\n1 0 0\n0 1 0\n3 0 1 2\n"),
    }
    for ext, data in files.items():
        p = tmp_path / f"latin.{ext}"
        p.write_bytes(data)
        assert load(p).triangles.tolist() == [[[0, 0, 0], [1, 0, 0], [0, 1, 0]]], ext


@pytest.mark.parametrize("faces, flags", [
    ([[0, 1, 2], [0, 1], [0, 1, 2, 3]], False),          # 3 + 2 + 4 indices = 3 x 3
    ([[0, 1, 2, 3], [0, 1, 4], [0, 1, 2, 3, 4]], False),  # 4 + 3 + 5 = 3 x 4
    ([[0, 1, 2, 3], [0, 1, 4], [0, 1, 2, 3, 4]], True),   # and a property after the list
])
def test_binary_ply_of_several_sizes_that_trimesh_misreads(tmp_path, faces, flags):
    """A binary PLY of faces of several sizes whose indices number as many as if every
    face had the first's size: trimesh reads it without an error, wrongly; kdray sees
    the counts and reads it itself."""
    import struct
    v = np.array([[0, 0, 0], [1, 0, 0], [1, 1, 0], [0, 1, 0], [0, 0, 1]], np.float32)
    head = ("ply\nformat binary_little_endian 1.0\nelement vertex 5\nproperty float x\n"
            "property float y\nproperty float z\nelement face %d\n"
            "property list uchar int vertex_indices\n%send_header\n"
            % (len(faces), "property int flags\n" if flags else ""))
    body = v.tobytes() + b"".join(struct.pack("<B%di" % len(f), len(f), *f)
                                  + (struct.pack("<i", 7) if flags else b"") for f in faces)
    p = tmp_path / "mixed.ply"
    p.write_bytes(head.encode() + body)
    want = []
    for f in faces:
        splits = [] if len(f) < 3 else ([(0, 1, 2), (2, 3, 0)] if len(f) == 4 else
                                        [(0, k, k + 1) for k in range(1, len(f) - 1)])
        want += [[f[a] for a in s] for s in splits]
    assert load(p).faces.tolist() == want


@pytest.mark.parametrize("name, text, message", [
    ("short_face.off", "OFF\n4 1 0\n0 0 0\n1 0 0\n1 1 0\n0 1 0\n4 0 1 2\n", "fewer corners"),
    ("few_faces.off", "OFF\n4 3 0\n0 0 0\n1 0 0\n1 1 0\n0 1 0\n3 0 1 2\n3 0 2 3\n",
     "ends before its counts"),
    ("few_faces.ply", "ply\nformat ascii 1.0\nelement vertex 4\nproperty float x\nproperty float y\n"
     "property float z\nelement face 5\nproperty list uchar int vertex_indices\nend_header\n"
     "0 0 0\n1 0 0\n1 1 0\n0 1 0\n3 0 1 2\n3 0 2 3\n", "counts 5 face elements, the file holds 2"),
])
def test_files_that_hold_less_than_they_say(tmp_path, name, text, message):
    """An OFF or ASCII PLY file whose lines hold less than its counts say is malformed
    (a MeshError), not read as far as it goes by trimesh's looser readers."""
    p = tmp_path / name
    p.write_text(text)
    with pytest.raises(MeshError, match=f"{name}: malformed.*{message}"):
        load(p)


def test_gltf_node_of_a_mesh_the_file_lacks(tmp_path):
    """A glTF node whose mesh index the file does not have is a MeshError, not a node
    left out without a word."""
    import base64
    import json
    import struct
    buf = struct.pack("<9f", 0, 0, 0, 1, 0, 0, 0, 1, 0)
    g = {"asset": {"version": "2.0"}, "scene": 0, "scenes": [{"nodes": [0, 1]}],
         "nodes": [{"name": "A", "mesh": 0}, {"name": "B", "mesh": 5}],
         "meshes": [{"primitives": [{"attributes": {"POSITION": 0}}]}],
         "accessors": [{"bufferView": 0, "componentType": 5126, "count": 3, "type": "VEC3",
                        "min": [0, 0, 0], "max": [1, 1, 0]}],
         "bufferViews": [{"buffer": 0, "byteLength": 36}],
         "buffers": [{"byteLength": 36, "uri": "data:application/octet-stream;base64,"
                      + base64.b64encode(buf).decode()}]}
    p = tmp_path / "dangling.gltf"
    p.write_text(json.dumps(g))
    with pytest.raises(MeshError, match="node 1 refers to mesh 5, and the file has 1"):
        load(p)
    g["nodes"][1]["mesh"] = 0
    p.write_text(json.dumps(g))
    assert len(load(p).faces) == 2


def _triangle_gltf():
    """A glTF of one triangle in two nodes (JSON, its buffer inline)."""
    import base64
    import struct
    buf = struct.pack("<9f", 0, 0, 0, 1, 0, 0, 0, 1, 0)
    return {"asset": {"version": "2.0"}, "scene": 0, "scenes": [{"nodes": [0, 2]}],
            "nodes": [{"name": "A", "mesh": 0, "children": [1]}, {"name": "B", "mesh": 0},
                      {"name": "C", "mesh": 0, "translation": [3, 0, 0]}],
            "meshes": [{"primitives": [{"attributes": {"POSITION": 0}}]}],
            "accessors": [{"bufferView": 0, "componentType": 5126, "count": 3,
                           "type": "VEC3", "min": [0, 0, 0], "max": [1, 1, 0]}],
            "bufferViews": [{"buffer": 0, "byteLength": 36}],
            "buffers": [{"byteLength": 36, "uri": "data:application/octet-stream;base64,"
                         + base64.b64encode(buf).decode()}]}


@pytest.mark.parametrize("edit, message", [
    (lambda g: g["nodes"][0]["children"].append(9), "node 0 refers to node 9, and the file has 3"),
    (lambda g: g.__setitem__("scene", 5), "its scene refers to scene 5, and the file has 1"),
    (lambda g: g["scenes"][0]["nodes"].append(7), "scene 0 refers to node 7"),
    (lambda g: g["meshes"][0]["primitives"][0].__setitem__("indices", 77),
     "a primitive of mesh 0 refers to accessor 77, and the file has 1"),
    (lambda g: g.pop("buffers"), "bufferView 0 refers to buffer 0, and the file has 0"),
    (lambda g: g["accessors"][0].__setitem__("bufferView", 4), "accessor 0 refers to bufferView 4"),
    (lambda g: g["nodes"][1].__setitem__("children", [0]), "its own ancestor"),
    (lambda g: g["nodes"][2].__setitem__("children", [1]), "node 1 is a child of nodes 0 and 2"),
    (lambda g: g["nodes"][1].__setitem__("children", [1]), "node 1 is a child of nodes 0 and 1"),
])
def test_gltf_references_that_do_not_hold(tmp_path, edit, message):
    """A glTF whose scene, nodes, accessors or buffers refer to what the file does not
    have, or whose nodes are not trees, is a MeshError saying which, before trimesh
    reads it (it had said "a face refers to a vertex that does not exist" for an
    IndexError, and read a cycle of nodes in part, with a warning)."""
    import json
    g = _triangle_gltf()
    p = tmp_path / "model.gltf"
    p.write_text(json.dumps(g))
    assert len(load(p).faces) == 3                  # the file as made: three nodes
    edit(g)
    p.write_text(json.dumps(g))
    with pytest.raises(MeshError, match=message):
        load(p)


def test_gltf_that_is_not_json(tmp_path):
    p = tmp_path / "model.gltf"
    p.write_text("solid this is not json")
    with pytest.raises(MeshError, match="is not a glTF file"):
        load(p)


def test_meshes_compare_by_their_arrays():
    """A Mesh equals its pickled and deep-copied twins (dataclass equality of numpy
    arrays raised ValueError), differs where an array, the name or the object names
    differ, and is not hashable."""
    import copy
    import pickle
    m = Mesh.from_arrays(np.eye(3), [[0, 1, 2]], name="m")
    assert m == pickle.loads(pickle.dumps(m)) == copy.deepcopy(m)
    assert m != Mesh.from_arrays(np.eye(3) * 2, [[0, 1, 2]], name="m")
    assert m != Mesh.from_arrays(np.eye(3), [[0, 1, 2]], name="n")
    assert m != "m"
    with pytest.raises(TypeError):
        hash(m)
