"""View-frustum culling: the kept faces are a superset of what the camera can hit, and
a tree of them gives the same images as the whole mesh's tree."""
import numpy as np
import pytest

import kdray
from kdray.cull import build_for_camera, cull_faces, mesh_origin, scene_box
from helpers import SCENES, real_mesh_arrays

SIZE = (96, 72)


def _same_images(a, b):
    """Names of the images that differ (depth and the other floats compared NaN-safe)."""
    assert list(a) == list(b)
    return [k for k in a if not np.array_equal(a[k], b[k], equal_nan=a[k].dtype.kind == "f")]


def _cameras(lo, hi):
    """Named cameras: framing all, a zoomed part, one inside looking sideways, one
    looking away from everything."""
    c, ext = (lo + hi) / 2, hi - lo
    w, h = SIZE
    part = c + np.array([0.3, 0.1, 0.0]) * ext
    return {
        "frame": kdray.Camera.frame(lo, hi, w, h),
        "part": kdray.Camera.look_at(part + [0, 0, 0.6 * ext[2]], part, fov_deg=20, width=w, height=h),
        "inside": kdray.Camera.look_at(c, c + [1.0, 0.2, 0.1], fov_deg=60, width=w, height=h),
        "away": kdray.Camera.look_at(c + [0, 0, 2 * ext[2]], c + [0, 0, 4 * ext[2]], width=w, height=h),
    }


def _check_scene(vertices, faces, cameras, expect_culled):
    full = kdray.build(vertices, faces)
    tracer = kdray.Tracer(full)
    aovs = ("depth", "normal", "bary", "id", "position")
    for name, camera in cameras.items():
        tree, n_left_out = build_for_camera(vertices, faces, camera)
        tree.validate()
        assert tree.n_input_tris == len(faces) and tree.origin.tolist() == full.origin.tolist()
        assert set(tree.tri_ids.tolist()) <= set(full.tri_ids.tolist())
        assert n_left_out == len(full.tri_ids) - len(tree.tri_ids) or (
            n_left_out == len(full.tri_ids) - 1 and len(tree.tri_ids) == 1)
        if name in expect_culled:
            assert n_left_out > 0, name
        want = tracer.render(camera, aovs=aovs)
        got = kdray.Tracer(tree).render(camera, aovs=aovs)
        assert _same_images(want, got) == [], name
        # conservative: every triangle the whole tree's image shows was kept
        seen = np.unique(want["id"])
        seen = seen[seen != kdray.trace.MISS]
        assert np.isin(seen, tree.tri_ids).all(), name
        assert np.isin(seen, cull_faces(vertices, faces, camera)).all(), name


def test_bunny_images_are_the_same_with_culling():
    vertices, faces = real_mesh_arrays("stanford-bunny.obj")
    lo, hi = scene_box(vertices, faces)
    _check_scene(vertices, faces, _cameras(lo, hi), expect_culled={"part", "inside", "away"})


def test_cornell_images_are_the_same_with_culling():
    mesh = kdray.load(SCENES / "cornell.obj")
    lo, hi = scene_box(mesh.vertices, mesh.faces)
    cameras = _cameras(lo, hi)
    cameras["json"] = kdray.Camera.from_json(SCENES / "cornell.json")
    cameras["corner"] = kdray.Camera.look_at((0.0, 0.5, 0.0), (-0.5, 0.2, -0.5), fov_deg=50,
                                             width=SIZE[0], height=SIZE[1])
    _check_scene(mesh.vertices, mesh.faces, cameras, expect_culled={"part", "inside", "away", "corner"})


def test_looking_away_gives_all_miss_images():
    vertices, faces = real_mesh_arrays("stanford-bunny.obj")
    lo, hi = scene_box(vertices, faces)
    camera = _cameras(lo, hi)["away"]
    assert len(cull_faces(vertices, faces, camera)) == 0
    tree, n_left_out = build_for_camera(vertices, faces, camera)
    assert len(tree.tri_ids) == 1 and n_left_out == len(faces) - 1   # the bunny has no degenerate face
    images = kdray.Tracer(tree).render(camera, aovs=("depth", "id", "normal"))
    assert np.all(images["depth"] == np.inf) and np.all(images["id"] == kdray.trace.MISS)
    assert np.all(images["normal"] == 0)


def _tiny_triangle(centre, size):
    """(3, 3) float64: a small triangle around `centre`, tilted off every axis."""
    return centre + size * np.array([[-1.0, -0.7, 0.3], [1.0, -0.4, -0.2], [0.1, 1.0, 0.1]])


@pytest.mark.parametrize("width,height", [(8, 6), (1, 5), (5, 1), (1, 1)])
def test_triangles_on_the_outermost_rays_are_kept_and_beyond_them_left_out(width, height):
    """Against brute force: a tiny triangle on each pixel-centre ray is hit and must be
    kept; one more than two pixels outside the image (or behind the eye) is left out."""
    K = np.array([[40.0, 3.0, width / 2 - 0.3], [0.0, 35.0, height / 2 + 0.2], [0, 0, 1]])
    pose = kdray.Camera.look_at((1.0, 2.0, 3.0), (0.2, -0.1, 0.4)).cam_to_world
    camera = kdray.Camera.from_intrinsics(K, pose, width, height)
    origins, directions = camera.rays()
    d = directions / np.linalg.norm(directions, axis=1)[:, None]
    tris = [_tiny_triangle(origins[0] + 5.0 * di, 1e-4) for di in d]
    kept_expected = len(tris)
    # outside: beyond the image's corners (and behind the eye)
    cam_dirs = np.array([[-width / 2 - 2, -height / 2 - 2], [width / 2 + 2, -height / 2 - 2],
                         [width / 2 + 2, height / 2 + 2], [-width / 2 - 2, height / 2 + 2]])
    for dx, dy in cam_dirs:
        ray = np.linalg.inv(K) @ [K[0, 2] + dx, K[1, 2] + dy, 1.0]
        world = pose[:3, :3] @ ray
        tris.append(_tiny_triangle(origins[0] + 5.0 * world / np.linalg.norm(world), 1e-4))
    tris.append(_tiny_triangle(origins[0] - 5.0 * camera.forward, 1e-4))
    vertices = np.concatenate(tris)
    faces = np.arange(len(vertices)).reshape(-1, 3)
    keep = cull_faces(vertices, faces, camera)
    assert keep.dtype == np.int64 and np.all(np.diff(keep) > 0)
    assert keep.tolist() == list(range(kept_expected))
    # and each kept triangle is really hit by its own ray (the brute-force oracle)
    tracer = kdray.Tracer(kdray.build(vertices, faces))
    ids = tracer.render(camera, aovs=("id",))["id"].ravel()
    assert ids.tolist() == list(range(kept_expected))


def test_culling_keeps_degenerate_free_ids_and_refuses_bad_meshes():
    with pytest.raises(kdray.MeshError):
        build_for_camera(np.zeros((3, 3)), np.array([[0, 1, 2]]),
                         kdray.Camera.look_at((0, 0, 1), (0, 0, 0)))


def test_nothing_usable_in_view_keeps_one_triangle_and_scale_is_taken():
    """The cull keeps degenerate triangles and those with a non-finite vertex: when only
    such are in view, one usable triangle out of view is kept (every ray misses), as
    when nothing is. A scale given is build's. Vertices float32 cannot hold: every
    face (none can be hit) rather than a crash, and build's MeshError from the tree."""
    camera = kdray.Camera.look_at((0, 0, 5), (0, 0, 0), fov_deg=30, width=16, height=12)
    v = np.array([[0, 0, 0], [0.1, 0, 0], [0.2, 0, 0], [0.05, 0.1, np.nan],
                  [100, 0, 0], [101, 0, 0], [100, 1, 0]], float)
    f = np.array([[0, 1, 2], [0, 1, 3], [4, 5, 6]])
    assert cull_faces(v, f, camera).tolist() == [0, 1]
    tree, left_out = build_for_camera(v, f, camera)
    assert tree.tri_ids.tolist() == [2] and left_out == 2
    assert (kdray.Tracer(tree).render(camera, aovs="id")["id"] == kdray.trace.MISS).all()
    tree, _ = build_for_camera(v, f, camera, scale=4.0)
    assert tree.scale == 4.0
    far = np.full((3, 3), 1e39) * np.eye(3)
    assert cull_faces(far, np.array([[0, 1, 2]]), camera).tolist() == [0]
    with pytest.raises(kdray.MeshError):
        build_for_camera(far, np.array([[0, 1, 2]]), camera)


def test_mesh_origin_is_the_builders(rng):
    """Unused and non-finite vertices are ignored as the builder ignores them."""
    vertices = rng.normal(size=(40, 3)) * [1.0, 3.0, 1e3] + [5.0, -2.0, 1e5]
    vertices[7] = [1e9, -1e9, 1e9]                          # unused
    vertices[11] = [np.nan, 0.0, 0.0]                       # used, not finite
    faces = rng.integers(0, 40, size=(30, 3))
    faces = faces[(faces != 7).all(axis=1)]
    faces[0] = [11, 1, 2]
    origin = kdray.build(vertices, faces).origin
    assert mesh_origin(vertices, faces).tolist() == origin.tolist()
    tree, _ = build_for_camera(vertices, faces, kdray.Camera.look_at((5, -2, 0), (5, -2, 1e5)))
    assert tree.origin.tolist() == origin.tolist()


def test_build_for_camera_refuses_an_origin_and_huge_origins_keep_quiet():
    """build_for_camera takes the whole mesh's origin: one given is a ParameterError
    (Python's TypeError before); cull_faces with an origin of 1e300 keeps every face
    without numpy's overflow warnings."""
    import warnings
    vertices, faces = real_mesh_arrays("spot.obj")
    lo, hi = scene_box(vertices, faces)
    camera = _cameras(lo, hi)["away"]
    with pytest.raises(kdray.ParameterError, match="origin"):
        build_for_camera(vertices, faces, camera, origin=(0.0, 0.0, 0.0))
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        kept = cull_faces(vertices, faces, camera, origin=[1e300, 0.0, 0.0])
    assert len(kept) == len(faces)
