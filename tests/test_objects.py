"""Object ids: which mesh of a scene each triangle came from (kdray.load's objects, the
tree's table and its file, the `object` AOV, Hits.object, the EXR and `kdray info`),
checked against the scenes' own construction and a float64 brute-force oracle."""
import json

import numpy as np
import pytest

import kdray
from kdray.errors import MeshError
from kdray.images import read_exr, read_object_names
from kdray.layout import MISS
from kdray.reference import brute_force
from kdray.tree import KdTree, object_ids
from helpers import SCENES, run

trimesh = pytest.importorskip("trimesh")
tf = trimesh.transformations

# -- a glTF scene: three nodes, two instances of one mesh, one under a parent --------------

BALL = trimesh.creation.icosphere(subdivisions=2, radius=0.6)
SLAB = trimesh.creation.box(extents=(4.0, 0.2, 3.0))
GROUP = tf.translation_matrix([0.2, 1.1, -0.3]) @ tf.rotation_matrix(0.4, [0, 1, 0])
"""The parent of "ball, right"; its own transform is applied after this one."""
NODES = {
    # name: (mesh, transform relative to the root)
    "floor": (SLAB, tf.translation_matrix([0.0, -0.1, 0.0])),
    "ball left": (BALL, tf.translation_matrix([-1.0, 0.6, 0.2])),
    "ball, right": (BALL, GROUP @ tf.translation_matrix([0.9, -0.4, 0.1])
                    @ tf.scale_matrix(0.8)),
}


def write_gltf(path):
    """A GLB of NODES: "ball left" and "ball, right" instance one mesh (one glTF mesh,
    two nodes), "ball, right" is a child of the node "group"."""
    scene = trimesh.Scene()
    scene.add_geometry(SLAB, node_name="floor", geom_name="slab",
                       transform=NODES["floor"][1])
    scene.add_geometry(BALL, node_name="ball left", geom_name="ball",
                       transform=NODES["ball left"][1])
    scene.graph.update(frame_to="group", frame_from=scene.graph.base_frame, matrix=GROUP)
    scene.graph.update(frame_to="ball, right", frame_from="group", geometry="ball",
                       matrix=np.linalg.inv(GROUP) @ NODES["ball, right"][1])
    scene.export(path)
    with open(path, "rb") as f:                      # the file holds two nodes of one mesh
        data = f.read()
    doc = json.loads(data[20:20 + int.from_bytes(data[12:16], "little")])
    assert len(doc["meshes"]) == 2 and sum("mesh" in n for n in doc["nodes"]) == 3
    return path


def node_triangles(name):
    """(k, 3, 3) float64 world triangles of a node, from NODES (the mesh's vertices as
    the file stores them: float32)."""
    mesh, transform = NODES[name]
    v = np.asarray(mesh.vertices, dtype=np.float32).astype(np.float64)
    v = v @ transform[:3, :3].T + transform[:3, 3]
    return v[np.asarray(mesh.faces)]


@pytest.fixture(scope="module")
def gltf_scene(tmp_path_factory):
    path = write_gltf(tmp_path_factory.mktemp("gltf") / "scene.glb")
    mesh = kdray.load(path)
    tree = kdray.build(mesh.vertices, mesh.faces, keep_double=True)
    return path, mesh, tree.with_objects(mesh.objects, mesh.object_names)


def sorted_rows(triangles):
    t = np.asarray(triangles).reshape(-1, 9)
    return t[np.lexsort(t.T[::-1])]


def test_gltf_objects_are_its_nodes(gltf_scene):
    """One object per node with a mesh, named after it, numbered in the order of the
    triangle ids; each object's triangles are its node's mesh under the node's whole
    transform (the parent's too); instances of one mesh are separate objects."""
    _, mesh, _ = gltf_scene
    assert sorted(mesh.object_names) == sorted(NODES)
    assert mesh.objects.dtype == np.uint32 and mesh.objects.shape == (len(mesh.faces),)
    first = [int(np.flatnonzero(mesh.objects == k)[0]) for k in range(len(NODES))]
    assert first == sorted(first) and first[0] == 0          # in order of first appearance
    for k, name in enumerate(mesh.object_names):
        mine = mesh.triangles[mesh.objects == k]
        want = node_triangles(name)
        assert len(mine) == len(want), name
        assert np.allclose(sorted_rows(mine), sorted_rows(want), atol=1e-6), name
        # a node's triangles are a run of ids: objects do not reorder triangles
        ids = np.flatnonzero(mesh.objects == k)
        assert np.array_equal(ids, np.arange(ids[0], ids[0] + len(ids)))


def gltf_camera(width=96, height=64):
    return kdray.Camera.look_at((0.5, 3.0, 5.0), (0.0, 0.4, 0.0), fov_deg=45, width=width,
                                height=height)


def test_object_image_against_ids_and_a_float64_oracle(gltf_scene, tracers):
    """The `object` image is objects[id] pixel by pixel; and independently of kdray's
    loader, tree and kernels, each object's pixels are where a float64 brute force over
    the nodes' transformed triangles (NODES) finds that node's triangles, but for
    pixels on a silhouette, where float32 rays may differ."""
    _, mesh, tree = gltf_scene
    tracer = tracers(tree)
    camera = gltf_camera()
    images = tracer.render(camera, aovs=("id", "object", "depth"))
    ids, objects = images["id"], images["object"]
    assert objects.dtype == np.uint32 and objects.shape == (64, 96)
    hit = ids != MISS
    assert np.array_equal(objects[hit], mesh.objects[ids[hit]])
    assert np.all(objects[~hit] == MISS)
    assert np.all(np.isin(np.arange(len(NODES)), objects))   # every node is seen
    # the oracle: the nodes' own triangles, labelled by node
    names = list(NODES)
    triangles = np.concatenate([node_triangles(n) for n in names])
    label = np.concatenate([np.full(len(NODES[n][0].faces), mesh.object_names.index(n))
                            for n in names]).astype(np.uint32)
    o, d = camera.rays()
    ref = brute_force(triangles, o, d)
    want = np.where(ref.prim >= 0, label[np.maximum(ref.prim, 0)], MISS).reshape(64, 96)
    differ = want != objects
    padded = np.pad(want, 1, mode="edge")
    edge = np.zeros_like(differ)
    for dy, dx in ((0, 1), (2, 1), (1, 0), (1, 2)):
        edge |= padded[dy:dy + 64, dx:dx + 96] != want
    assert not np.any(differ & ~edge), np.argwhere(differ & ~edge)[:5]
    assert differ.sum() <= 0.01 * differ.size
    for k in range(len(NODES)):
        assert np.count_nonzero(want == k) > 50


def test_render_of_only_objects_computes_only_ids(gltf_scene):
    """object comes from the kernel's ids: a render of only `object` compiles only
    OUT_ID and returns no `id`; the same image as with ids."""
    _, _, tree = gltf_scene
    tracer = kdray.Tracer(tree)
    camera = gltf_camera(40, 24)
    images = tracer.render(camera, aovs="object")
    assert list(images) == ["object"]
    (key,) = tracer._programs
    assert "OUT_ID" in dict(key)
    assert not {"OUT_T", "OUT_UV", "OUT_NORMAL", "STATS"} & dict(key).keys()
    both = tracer.render(camera, aovs=("object", "id"))
    assert np.array_equal(both["object"], images["object"])
    assert np.array_equal(images["object"], object_ids(both["id"], tree.objects).reshape(24, 40))
    assert "object" in kdray.render.parse_aovs("all")


def test_double_precision_renders_objects(gltf_scene, tracers):
    _, _, tree = gltf_scene
    tracer = tracers(tree)
    camera = gltf_camera(40, 24)
    single = tracer.render(camera, aovs=("object", "depth"))
    double = tracer.render(camera, aovs=("object", "depth"), precision="double")
    assert list(double) == ["object", "depth"] and double["depth"].dtype == np.float64
    assert double["object"].dtype == np.uint32
    assert np.array_equal(double["object"], single["object"])


def test_hits_object(gltf_scene, tracers):
    """Hits.object is objects[prim], MISS on a miss, looked up on first access only;
    a slice, mask or index of Hits keeps the table; precision="double" too."""
    _, mesh, tree = gltf_scene
    tracer = tracers(tree)
    camera = gltf_camera(40, 24)
    o, d = tracer.camera_rays(camera)
    o = np.concatenate([o, [[0.0, 50.0, 0.0]]])
    d = np.concatenate([d, [[0.0, 1.0, 0.0]]])                 # straight up: a miss
    hits = tracer.trace(o, d)
    assert "object" not in vars(hits)                          # nothing paid yet
    objects = hits.object
    assert "object" in vars(hits) and hits.object is objects   # computed once
    assert objects.dtype == np.uint32 and objects.shape == (len(d),)
    assert objects[-1] == MISS and hits.prim[-1] == MISS
    hit = hits.hit
    assert np.array_equal(objects[hit], mesh.objects[hits.prim[hit]])
    assert np.all(objects[~hit] == MISS)
    image = tracer.render(camera, aovs="object")["object"]
    assert np.array_equal(objects[:-1], image.reshape(-1))
    for index in (slice(3, 40, 2), hit, np.flatnonzero(~hit)[:5], -1):
        part = hits[index]
        assert part.object_table is tree.objects
        assert np.array_equal(part.object, objects[index])
    double = tracer.trace(o, d, precision="double")
    assert double.t.dtype == np.float64 and np.array_equal(double.object, objects)
    # image-shaped hits: any index of the rays' axes takes whole rows of normals
    image = tracer.trace(o[:-1].reshape(24, 40, 3), d[:-1].reshape(24, 40, 3))
    for index in ((Ellipsis, 2), (slice(None), 2), 5, image.hit, (3, 7), (Ellipsis,)):
        part = image[index]
        assert np.array_equal(part.t, image.t[index])
        each = np.stack([image.normal[..., c][index] for c in range(3)], axis=-1)
        assert part.normal.shape == part.t.shape + (3,) and np.array_equal(part.normal, each)


# -- OBJ groups and objects ---------------------------------------------------------------

def key(triangle):
    """A triangle's vertices as bytes, whatever their order."""
    t = np.asarray(triangle, dtype=np.float64)
    return t[np.lexsort(t.T[::-1])].tobytes()


def obj_scene(tmp_path):
    """An OBJ with `o`, `g` and `usemtl` lines in awkward order, a quad, faces before any
    group and a group that comes back. Returns (path, the expected object name of each
    face line's triangles: {key(triangle): name})."""
    rng = np.random.default_rng(3)
    lines, want = [], {}
    n_v = 0

    def face(name, corners=3):
        nonlocal n_v
        v = rng.normal(size=(corners, 3)).round(6)
        if corners == 4:                        # a planar quad
            v[:, 2] = v[0, 2]
        for p in v:
            lines.append(f"v {float(p[0])!r} {float(p[1])!r} {float(p[2])!r}")
        lines.append("f " + " ".join(str(n_v + i + 1) for i in range(corners)))
        n_v += corners
        # a quad's triangles, whichever diagonal trimesh takes
        for tri in ([[0, 1, 2]] if corners == 3 else [[0, 1, 2], [0, 2, 3], [1, 2, 3], [0, 1, 3]]):
            want[key(v[tri])] = name
        return v

    face("scene.obj")                           # before any o or g: named after the file
    lines.append("usemtl red")
    face("scene.obj")
    lines.append("o car")
    face("car")
    lines.append("g body")
    face("car_body")
    lines.append("usemtl blue")
    face("car_body", corners=4)
    lines.append("g wheel")
    face("car_wheel")
    lines.append("usemtl red")
    face("car_wheel")
    lines.append("g body")                      # back to a group seen before
    face("car_body")
    lines.append("o tree")
    face("tree_body")                           # `o` does not end the group
    face("tree_body", corners=4)
    path = tmp_path / "scene.obj"
    path.write_text("\n".join(lines) + "\n")
    return path, want


def test_obj_objects_are_its_o_and_g_groups(tmp_path):
    path, want = obj_scene(tmp_path)
    mesh = kdray.load(path)
    got = [mesh.object_names[k] for k in mesh.objects]
    expected = [want[key(t)] for t in mesh.triangles]
    assert got == expected
    # triangle ids in the file's order, whatever its materials and groups
    assert got == (["scene.obj"] * 2 + ["car"] + ["car_body"] * 3 + ["car_wheel"] * 2
                   + ["car_body"] + ["tree_body"] * 3)
    assert mesh.object_names == ("scene.obj", "car", "car_body", "car_wheel", "tree_body")
    assert mesh.objects[0] == 0 and list(np.unique(mesh.objects, return_index=True)[1]) == sorted(
        np.unique(mesh.objects, return_index=True)[1])


def test_obj_gz_objects(tmp_path):
    import gzip
    path, want = obj_scene(tmp_path)
    zipped = tmp_path / "scene.obj.gz"
    zipped.write_bytes(gzip.compress(path.read_bytes()))
    a, b = kdray.load(path), kdray.load(zipped)
    assert np.array_equal(a.faces, b.faces) and np.array_equal(a.objects, b.objects)
    assert a.object_names == b.object_names


def test_obj_groups_of_equal_triangles(tmp_path):
    """Exactly equal triangles in two groups: each group keeps one (which one is which
    is not defined); the triangles of other groups are matched exactly."""
    path = tmp_path / "dup.obj"
    path.write_text("v 0 0 0\nv 1 0 0\nv 0 1 0\nv 5 5 5\n"
                    "g a\nf 1 2 3\nf 1 2 4\ng b\nf 1 2 3\n")
    mesh = kdray.load(path)
    assert sorted(mesh.object_names) == ["a", "b"]
    names = [mesh.object_names[k] for k in mesh.objects]
    assert sorted(names) == ["a", "a", "b"]
    assert names[1] == "a"                          # the one triangle only in a


def test_obj_matching_when_hashes_collide(tmp_path, monkeypatch, caplog):
    """The two reads' triangles are paired by a hash of their bits; should hashes
    collide, by the bits; should the reads differ, the file is one object, with a
    warning."""
    import sys
    load_module = sys.modules["kdray.load"]
    path, want = obj_scene(tmp_path)
    good = kdray.load(path)
    monkeypatch.setattr(load_module, "_row_hash", lambda rows: np.zeros(len(rows), np.uint64))
    same = kdray.load(path)
    assert np.array_equal(same.objects, good.objects) and same.object_names == good.object_names
    monkeypatch.setattr(load_module, "_row_bytes", lambda rows: np.arange(len(rows))[::-1].copy())
    one = kdray.load(path)
    assert one.object_names == ("scene.obj",) and not one.objects.any()
    assert "o/g groups hold other triangles" in caplog.text


def test_files_of_one_object(tmp_path):
    """An OBJ with no o or g (usemtl does not make objects), one with a single group,
    and an STL: one object, 0, named after the file."""
    (tmp_path / "m.obj").write_text("v 0 0 0\nv 1 0 0\nv 0 1 0\nv 0 0 1\n"
                                    "usemtl a\nf 1 2 3\nusemtl b\nf 1 2 4\n")
    (tmp_path / "g.obj").write_text("v 0 0 0\nv 1 0 0\nv 0 1 0\nv 0 0 1\n"
                                    "o thing\nf 1 2 3\nf 1 2 4\n")
    trimesh.creation.box().export(tmp_path / "b.stl")
    for name in ("m.obj", "g.obj", "b.stl"):
        mesh = kdray.load(tmp_path / name)
        assert mesh.object_names == (name,) and not mesh.objects.any()
        assert mesh.objects.dtype == np.uint32 and len(mesh.objects) == len(mesh.faces)


GLTF_VERTICES = np.array([[0, 0, 0], [1, 0, 0], [0, 1, 0], [0, 0, 1]], np.float32)
GLTF_INDICES = {1: np.array([0, 1, 2], np.uint32), 2: np.array([0, 1, 3, 1, 2, 3], np.uint32)}


def gltf_doc(roots, nodes, meshes):
    """A glTF document (a dict) of the scene `roots` (node indices), `nodes` as given
    and meshes (a list of each mesh's primitives, each an accessor of indices: 1, one
    triangle of GLTF_VERTICES, or 2, two; or a (indices, mode) pair), its buffer
    inline."""
    import base64
    buf = GLTF_VERTICES.tobytes() + GLTF_INDICES[1].tobytes() + GLTF_INDICES[2].tobytes()
    return {"asset": {"version": "2.0"}, "scene": 0, "scenes": [{"nodes": roots}],
            "nodes": nodes,
            "meshes": [{"primitives": [{"attributes": {"POSITION": 0}, "indices": i, "mode": m}
                                       for i, m in (p if isinstance(p, tuple) else (p, 4)
                                                    for p in mesh)]}
                       for mesh in meshes],
            "buffers": [{"byteLength": len(buf), "uri": "data:application/octet-stream;base64,"
                         + base64.b64encode(buf).decode()}],
            "bufferViews": [{"buffer": 0, "byteOffset": 0, "byteLength": 48},
                            {"buffer": 0, "byteOffset": 48, "byteLength": 12},
                            {"buffer": 0, "byteOffset": 60, "byteLength": 24}],
            "accessors": [{"bufferView": 0, "componentType": 5126, "count": 4, "type": "VEC3",
                           "min": [0, 0, 0], "max": [1, 1, 1]},
                          {"bufferView": 1, "componentType": 5125, "count": 3,
                           "type": "SCALAR"},
                          {"bufferView": 2, "componentType": 5125, "count": 6,
                           "type": "SCALAR"}]}


def test_gltf_mesh_of_several_primitives_is_one_object(tmp_path):
    """trimesh gives each primitive of a glTF mesh its own node, randomly named: they
    are one object, named after their glTF node, the same on every load."""
    doc = gltf_doc([0], [{"name": "Car", "mesh": 0, "children": [1]},
                         {"name": "Wheel", "mesh": 0, "translation": [5, 0, 0]}],
                   [[1, 2]])
    path = tmp_path / "car.gltf"
    path.write_text(json.dumps(doc))
    a, b = kdray.load(path), kdray.load(path)
    assert a.object_names == b.object_names and sorted(a.object_names) == ["Car", "Wheel"]
    assert np.array_equal(a.objects, b.objects)
    wheel = a.objects == a.object_names.index("Wheel")
    assert wheel.sum() == 3 and np.all(a.triangles[wheel][..., 0] >= 5)


def test_gltf_nodes_in_the_files_order(tmp_path):
    """A glTF scene's meshes and objects come in the file's order: its scene's nodes
    depth first from the roots, children in their listed order (trimesh walks them the
    other way round), a mesh's primitives in turn; an unnamed node is named by its
    index, a repeated name made unique. The same through a GLB (trimesh's export) and
    gzip."""
    import gzip
    doc = gltf_doc([1, 0, 4], [{"name": "box", "mesh": 0, "children": [3, 2]},
                               {"mesh": 0, "translation": [100, 0, 0]},
                               {"name": "box", "mesh": 0, "translation": [20, 0, 0]},
                               {"name": "wheel", "mesh": 1, "translation": [10, 0, 0]},
                               {"name": "empty", "children": [5]},
                               {"name": "deep", "mesh": 0, "translation": [50, 0, 0]}],
                   [[1], [1, 2]])
    v, i1, i2 = GLTF_VERTICES, GLTF_INDICES[1], GLTF_INDICES[2]
    path = tmp_path / "nodes.gltf"
    path.write_text(json.dumps(doc))
    mesh = kdray.load(path)
    assert mesh.object_names == ("1", "box", "wheel", "box_1", "deep")
    want = [(100, i1), (0, i1), (10, i1), (10, i2), (20, i1), (50, i1)]
    expected = np.concatenate([v[i.reshape(-1, 3)] + np.float32([x, 0, 0]) for x, i in want])
    np.testing.assert_array_equal(mesh.triangles, expected)
    assert mesh.objects.tolist() == [0, 1, 2, 2, 2, 3, 4]
    # a GLB as trimesh writes one, and the same gzipped
    scene = trimesh.Scene()
    for k, name in enumerate(["a", "b", "c", "d"]):
        scene.add_geometry(trimesh.creation.box(), node_name=name, geom_name=f"g{name}",
                           transform=trimesh.transformations.translation_matrix([10 * k, 0, 0]))
    glb = tmp_path / "abcd.glb"
    scene.export(glb)
    zipped = tmp_path / "abcd.glb.gz"
    zipped.write_bytes(gzip.compress(glb.read_bytes()))
    for p in (glb, zipped):
        m = kdray.load(p)
        assert m.object_names == ("a", "b", "c", "d")
        assert np.array_equal(m.triangles.min(axis=(1, 2))[::12], [-0.5, -0.5, -0.5, -0.5])
        assert np.array_equal(m.triangles[::12, :, 0].min(axis=1), [-0.5, 9.5, 19.5, 29.5])


def test_gltf_nodes_not_matched_keep_trimeshs_order(tmp_path, monkeypatch, caplog):
    """Where the file's nodes cannot be matched to trimesh's (a name it gave another
    way), the meshes keep trimesh's order, with a warning."""
    import sys
    scene = trimesh.Scene()
    for k, name in enumerate(["a", "b"]):
        scene.add_geometry(trimesh.creation.box(), node_name=name, geom_name=f"g{name}",
                           transform=trimesh.transformations.translation_matrix([10 * k, 0, 0]))
    glb = tmp_path / "ab.glb"
    scene.export(glb)
    monkeypatch.setattr(sys.modules["kdray.load"], "_gltf_node_ranks",
                        lambda header: {"a": 0})
    m = kdray.load(glb)
    assert sorted(m.object_names) == ["a", "b"] and len(m.faces) == 24
    assert "cannot match its scene's nodes" in caplog.text


def test_gltf_what_trimesh_reads_wrong(tmp_path, caplog):
    """glTF parts trimesh's reader gets wrong without a word: a TRIANGLE_FAN primitive
    (left out) and a sparse accessor (read without its values) are refused; a camera
    node's children (unreachable in trimesh's graph: a ValueError) are left out with
    a warning; a glTF node whose mesh has one triangle primitive of several (the
    others lines) is its own object, not its parent's; a node named as trimesh's base
    frame ("world") keeps the file's order."""
    def load_doc(name, doc):
        path = tmp_path / name
        path.write_text(json.dumps(doc))
        return kdray.load(path)

    fan = gltf_doc([0], [{"name": "a", "mesh": 0}], [[(1, 6)]])
    with pytest.raises(MeshError, match="mesh 0 is a TRIANGLE_FAN"):
        load_doc("fan.gltf", fan)
    sparse = gltf_doc([0], [{"name": "a", "mesh": 0}], [[1]])
    sparse["accessors"][0]["sparse"] = {"count": 1, "indices": {"bufferView": 1, "componentType": 5125},
                                        "values": {"bufferView": 0}}
    with pytest.raises(MeshError, match="accessor 0 is sparse"):
        load_doc("sparse.gltf", sparse)
    camera = gltf_doc([0, 2], [{"name": "eye", "camera": 0, "children": [1]},
                               {"name": "held", "mesh": 0}, {"name": "free", "mesh": 0}], [[1]])
    camera["cameras"] = [{"type": "perspective", "perspective": {"yfov": 1.0, "znear": 0.1}}]
    m = load_doc("camera.gltf", camera)
    assert len(m.faces) == 1                            # free's; held's left out
    assert "held left out" in caplog.text
    lines = gltf_doc([0], [{"name": "parent", "mesh": 1, "children": [1]},
                           {"name": "child", "mesh": 0, "translation": [0, 0, 1]}],
                     [[1, (2, 1)], [1]])                 # mesh 0: a triangle and lines
    m = load_doc("lines.gltf", lines)
    assert m.object_names == ("parent", "child") and m.objects.tolist() == [0, 1]
    assert m.triangles[1, :, 2].tolist() == [1, 1, 1]
    world = gltf_doc([0, 1], [{"name": "world", "mesh": 0},
                              {"name": "b", "mesh": 0, "translation": [10, 0, 0]}], [[1]])
    m = load_doc("world.gltf", world)
    assert m.object_names == ("world_1", "b") and m.triangles[:, 0, 0].tolist() == [0, 10]
    assert "cannot match" not in caplog.text


def test_single_mesh_is_object_0(tracers):
    """A mesh of one object: no table in the tree, object 0 on every hit, MISS on a
    miss, in the image and in Hits.object."""
    mesh = kdray.load(SCENES / "cornell.obj")
    assert mesh.object_names == ("cornell.obj",) and not mesh.objects.any()
    tree = kdray.build(mesh.vertices, mesh.faces).with_objects(mesh.objects, mesh.object_names)
    assert tree.objects is None and tree.object_names == () and tree.n_objects == 1
    tracer = tracers(tree)
    lo, hi = tree.world_box()
    camera = kdray.Camera.look_at(hi + (hi - lo), (lo + hi) / 2, width=32, height=24)
    images = tracer.render(camera, aovs=("id", "object"))
    hit = images["id"] != MISS
    assert hit.any() and (~hit).any()
    assert np.all(images["object"][hit] == 0) and np.all(images["object"][~hit] == MISS)
    o, d = tracer.camera_rays(camera)
    hits = tracer.trace(o, d)
    assert np.array_equal(hits.object, images["object"].reshape(-1))
    away = tracer.trace(hi + (hi - lo), (hi - lo)[None])
    assert away.prim[0] == MISS and away.object.tolist() == [MISS]


def test_object_ids_lookup():
    ids = np.array([2, MISS, 0, 1, 2], np.uint32)
    assert object_ids(ids, np.array([1, 0, 2], np.uint32)).tolist() == [2, MISS, 1, 0, 2]
    assert object_ids(ids, None).tolist() == [0, MISS, 0, 0, 0]
    assert object_ids(np.zeros(0, np.uint32), None).dtype == np.uint32


def test_mesh_from_arrays_objects():
    v, f = np.random.default_rng(0).random((9, 3)), np.arange(9).reshape(3, 3)
    one = kdray.Mesh.from_arrays(v, f, name="thing")
    assert one.objects.tolist() == [0, 0, 0] and one.object_names == ("thing",)
    two = kdray.Mesh.from_arrays(v, f, objects=[1, 0, 1], object_names=["a", "b"])
    assert two.objects.dtype == np.uint32 and two.object_names == ("a", "b")
    numbered = kdray.Mesh.from_arrays(v, f, objects=np.array([0, 2, 2]))
    assert numbered.object_names == ("object 0", "object 1", "object 2")
    for objects, names, match in [([0, 1], ["a", "b"], r"\(3,\)"),
                                  ([0, 1, 2], ["a", "b"], "out of range"),
                                  ([0, -1, 0], ["a", "b"], "out of range"),
                                  ([0, 1, 0], ["a", "a"], "twice"),
                                  ([0, 1, 0], "ab", "strings"),
                                  ([0, 1, 0], 5, "strings"),
                                  ([0, 1, 0], ["a", "\ud800"], "Unicode"),
                                  ([0, 1, 0], [], "at least one"),
                                  ([0.5, 1, 0], ["a", "b"], "integers"),
                                  (None, ["a"], "without objects"),
                                  ([0, 7, 0], None, "no object_names")]:
        with pytest.raises(MeshError, match=match):
            kdray.Mesh.from_arrays(v, f, name="m", objects=objects, object_names=names)


# -- the tree file, the command line and the EXR --------------------------------------------

def test_tree_file_round_trip_keeps_objects(gltf_scene, tmp_path):
    _, mesh, tree = gltf_scene
    path = tmp_path / "scene.kdt"
    tree.save(path)
    back = KdTree.load(path)
    assert int.from_bytes(path.read_bytes()[8:12], "little") == 3
    assert back == tree and back.object_names == mesh.object_names
    assert np.array_equal(back.objects, mesh.objects)
    back.validate()


def test_cli_build_info_and_render_with_objects(gltf_scene, tmp_path, capsys):
    """`kdray build --dump` writes the objects (version 3), `kdray info` lists them,
    `kdray render` (from the mesh and from --tree) writes the object channel and the
    names into the EXR."""
    path, mesh, _ = gltf_scene
    kdt = tmp_path / "scene.kdt"
    code, out, err = run(capsys, "build", path, "--dump", kdt)
    assert code == 0, err
    assert int.from_bytes(kdt.read_bytes()[8:12], "little") == 3
    code, out, err = run(capsys, "info", kdt, "--check")
    assert code == 0, err
    assert "objects            3\n" in out
    for k, name in enumerate(mesh.object_names):
        assert f"{f'  object {k}':<19}{name}\n" in out
    assert out.index("objects") < out.index("check              ok")
    for extra in ([], ["--tree", kdt]):
        exr = tmp_path / "scene.exr"
        code, out, err = run(capsys, "render", path, "--size", "48x32", "--aov", "object,depth",
                             "-o", exr, *extra)
        assert code == 0, err
        assert "of 1536 pixels hit" in out
        images = read_exr(exr)
        assert images["object"].dtype == np.uint32
        assert set(np.unique(images["object"])) <= {0, 1, 2, MISS}
        assert read_object_names(exr) == mesh.object_names
        assert np.array_equal(np.isfinite(images["depth"]), images["object"] != MISS)


def test_cli_single_object_stays_version_1(tmp_path, capsys):
    kdt = tmp_path / "cornell.kdt"
    code, _, err = run(capsys, "build", SCENES / "cornell.obj", "--dump", kdt)
    assert code == 0, err
    assert int.from_bytes(kdt.read_bytes()[8:12], "little") == 1
    mesh = kdray.load(SCENES / "cornell.obj")
    assert kdt.read_bytes() == kdray.build(mesh.vertices, mesh.faces).to_bytes()
    code, out, err = run(capsys, "info", kdt)
    assert code == 0 and "objects            1 (no object table: every triangle is object 0)\n" in out
    exr = tmp_path / "c.exr"
    code, out, err = run(capsys, "render", SCENES / "cornell.obj", "--size", "16x12", "--aov",
                         "object,id", "-o", exr)
    assert code == 0, err
    assert read_object_names(exr) is None
    images = read_exr(exr)
    assert np.array_equal(images["object"], np.where(images["id"] == MISS, MISS, 0))


def test_cli_info_lists_the_first_20_objects(tmp_path, capsys):
    rng = np.random.default_rng(1)
    v = rng.random((75, 3))
    f = np.arange(75).reshape(25, 3)
    names = [f"part {i}, \"{chr(0x3b1 + i % 20)}\"" for i in range(25)]
    tree = kdray.build(v, f).with_objects(np.arange(25)[::-1], names)
    tree.save(tmp_path / "t.kdt")
    code, out, err = run(capsys, "info", tmp_path / "t.kdt")
    assert code == 0, err
    assert "objects            25\n" in out
    assert f"{'  object 19':<19}{names[19]}\n" in out
    assert "object 20" not in out and "... and 5 more\n" in out


def test_cli_aov_help_names_object(capsys):
    code, out, _ = run(capsys, "render", "--help")
    assert code == 0 and "object" in out
