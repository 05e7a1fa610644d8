"""Leaving out the triangles no primary ray of a camera can reach (view-frustum culling).

    keep = cull_faces(vertices, faces, camera)              # (k,) int64 face rows
    tree, n_left_out = build_for_camera(vertices, faces, camera, K_T=15.0)
    lo, hi = scene_box(vertices, faces)                     # what framing uses
    origin = mesh_origin(vertices, faces)                   # the builder's default origin

The frustum is the cone from the eye through the outermost pixel centres (pixels
(0, 0), (W-1, 0), (W-1, H-1), (0, H-1), sampled at i + 0.5, j + 0.5), cut by the
plane z = 0 through the eye. A triangle is left out only when its three vertices lie
strictly outside one of these five planes by more than a margin, so no ray of the
camera can meet it; everything else is kept (a superset of the reachable triangles).

The margin covers what the kernel rounds: ray directions computed in float32 from a
float32 M = R K^-1 (an angle of a few float32 epsilons, padded to 1e-4 of the
frustum's angle plus 1e-5 of the direction's rounding scale), the float32 eye and
triangles relative to the tree's origin and the triangle test's own error (1e-5 of
the scene's size, measured from the origin). A vertex at distance r from the eye is
outside a plane when its signed distance is below -(angle_margin r + abs_margin);
since r is convex, a triangle whose vertices all are is outside everywhere.

A tree built over the kept faces uses the whole mesh's origin, so it stores the same
float32 triangles as the whole mesh's tree, and its `tri_ids` point into the input:
images of the camera are the same as with the whole mesh.
"""
import dataclasses
import logging

import numpy as np

from .builder import build
from .builder.prepare import FLOAT32_MAX, check_origin, mesh_origin, mesh_scale, prepare
from .errors import MeshError, ParameterError
from .mesh import check_arrays

log = logging.getLogger(__name__)

ANGLE_MARGIN = 1e-4
"""Relative padding of the frustum's angle (radians of padding per radian of view)."""

ROUNDING_MARGIN = 1e-5
"""Padding of the rays' direction, in units of their float32 rounding scale
|M||[x, y, 1]| / |M [x, y, 1]| (float32's epsilon is 1.2e-7: about 80 epsilons)."""

SCENE_MARGIN = 1e-5
"""Absolute padding, as a fraction of the scene's size (the largest distance of the eye
or a vertex from the origin): float32 eye and triangles, the triangle test's slack."""


def _frustum(camera):
    """Inward unit normals of the frustum's planes through the eye, in camera axes,
    and the angle margin (radians): (planes (5, 3) float64, angle_margin float).

    Each side plane holds one edge of the rectangle of pixel centres (in the z = 1
    image plane): it contains the corner ray and the edge's direction K^-1 e_x or
    K^-1 e_y, so an image one pixel wide or high still has four proper planes (two of
    them the same plane, facing opposite ways)."""
    w, h = camera.width, camera.height
    k_inv = np.linalg.inv(camera.K)
    pixels = np.array([[0.5, 0.5, 1.0], [w - 0.5, 0.5, 1.0], [w - 0.5, h - 0.5, 1.0],
                       [0.5, h - 0.5, 1.0]])
    corners = pixels @ k_inv.T                                  # (4, 3) ray directions
    kx, ky = k_inv[:, 0], k_inv[:, 1]                           # image x and y directions
    # (corner on the edge, edge direction, a direction pointing into the image)
    sides = [(corners[0], kx, ky), (corners[3], kx, -ky), (corners[0], ky, kx), (corners[1], ky, -kx)]
    normals = np.array([np.cross(corner, along) for corner, along, _ in sides])
    inward = np.array([into for _, _, into in sides])
    normals *= np.sign(np.sum(normals * inward, axis=1))[:, None]
    normals /= np.linalg.norm(normals, axis=1)[:, None]
    planes = np.vstack([normals, [0.0, 0.0, 1.0]])              # and z = 0 (behind the eye)

    unit = corners / np.linalg.norm(corners, axis=1)[:, None]
    angle = max(np.arccos(np.clip(unit[0] @ unit[2], -1.0, 1.0)),
                np.arccos(np.clip(unit[1] @ unit[3], -1.0, 1.0)))
    # rounding scale of M [x, y, 1] (R is a rotation: |M e_i| = |K^-1 e_i|)
    col = np.linalg.norm(k_inv, axis=0)
    scale = (np.abs(pixels) @ col) / np.linalg.norm(corners, axis=1)
    return planes, ANGLE_MARGIN * angle + ROUNDING_MARGIN * scale.max()


def cull_faces(vertices, faces, camera, origin=None):
    """Rows of `faces` that some primary ray of `camera` may hit.

    vertices : (n, 3) float64 world coordinates;  faces : (m, 3) int
    camera : kdray.Camera (width, height, K, cam_to_world; OpenCV axes)
    origin : (3,) float64 the tree's float32 data will be relative to; None = the
        centre of the box of the finite vertices the faces use (the builder's default)
    Returns (k,) int64 ascending face indices: every triangle a ray can reach, and
    possibly some it cannot (see the module docstring); every face for a camera that is
    not a pinhole (kdray.lens: no frustum of planes bounds its rays). Raises MeshError
    for bad arrays, ParameterError for an origin that is not 3 finite numbers.
    """
    v, f = check_arrays(vertices, faces)
    if origin is not None:
        origin = check_origin(origin)
    if getattr(camera, "model", "pinhole") != "pinhole":
        return np.arange(len(f), dtype=np.int64)
    used = np.zeros(len(v), dtype=bool)
    used[f.ravel()] = True
    used &= (np.abs(v) <= FLOAT32_MAX).all(axis=1)     # what the builder keeps (NaN too)
    if not used.any():                  # no vertex float32 holds: no triangle can be hit
        return np.arange(len(f), dtype=np.int64)
    if origin is None:
        origin = mesh_origin(v, f)
    eye = np.asarray(camera.cam_to_world, dtype=np.float64)[:3, 3]
    rotation = np.asarray(camera.cam_to_world, dtype=np.float64)[:3, :3]
    with np.errstate(over="ignore", invalid="ignore"):     # an origin of 1e300: inf, all kept
        size = max(np.linalg.norm(v[used] - origin, axis=1).max(), np.linalg.norm(eye - origin))
    abs_margin = SCENE_MARGIN * size

    planes, angle_margin = _frustum(camera)
    with np.errstate(invalid="ignore", over="ignore"):
        p = (v - eye) @ rotation                                # (n, 3) camera axes
        r = np.linalg.norm(p, axis=1)
        outside = (p @ planes.T) < -(angle_margin * r + abs_margin)[:, None]   # (n, 5)
    # non-finite vertices compare False: never outside, so their triangles are kept
    unreachable = outside[f].all(axis=1).any(axis=1)            # (m,)
    return np.flatnonzero(~unreachable).astype(np.int64)


def scene_box(vertices, faces):
    """(lo, hi): (3,) float64 world box of the triangles a tree of the whole mesh keeps,
    the box `kdray render` frames when no camera is given (tree.world_box()).
    Raises MeshError as `build` does."""
    prep = prepare(vertices, faces)
    return (prep.origin + prep.scale * prep.bounds[0].astype(np.float64),
            prep.origin + prep.scale * prep.bounds[1].astype(np.float64))


def build_for_camera(vertices, faces, camera, **build_params):
    """A KdTree of the triangles `camera` may see; its images equal the whole mesh's.

    vertices : (n, 3) float64;  faces : (m, 3) int;  camera : kdray.Camera
    build_params : keyword arguments of kdray.builder.build (K_T, K_I, scale, ...; not
        origin)
    Returns (tree, n_left_out): the tree, with the whole mesh's origin and scale (or the
    scale given), `tri_ids` pointing into `faces` and `n_input_tris` = m, and the
    number of triangles the cull left out (degenerate ones among them included; the
    builder leaves out the degenerate ones it is given, so m - n_left_out -
    len(tree.tri_ids) of those).
    When the camera sees nothing the builder keeps (nothing, or only degenerate
    triangles), one unreachable triangle (the first non-degenerate one) is kept so that
    the tree is not empty: every ray misses (n_left_out then m - 1: that one counts as
    kept). ParameterError for an `origin` among build_params.
    Raises MeshError (as build does) when the mesh has no usable triangle.
    """
    v, f = check_arrays(vertices, faces)
    if "origin" in build_params:
        raise ParameterError("build_for_camera takes the whole mesh's origin; origin is "
                             "not one of its build parameters")
    origin = mesh_origin(v, f)
    if origin is None:
        prepare(v, f)                                           # raises build's MeshError
    # a scale given is build's (checked there), else the whole mesh's
    scale = build_params.pop("scale", None)
    if scale is None:
        scale = mesh_scale(v, f)
    keep = cull_faces(v, f, camera, origin=origin)
    keep_double = build_params.pop("keep_double", False)
    tree = None
    if len(keep):
        try:
            tree = build(v, f[keep], origin=origin, scale=scale, **build_params)
        except MeshError:
            pass                    # only triangles the builder leaves out: as nothing
    if tree is None:
        # nothing in view that the builder keeps (the cull keeps degenerate triangles
        # and those with a non-finite vertex): the whole mesh's first usable triangle,
        # or the whole mesh's MeshError
        keep = prepare(v, f, origin, scale=scale).tri_ids[:1].astype(np.int64)
        tree = build(v, f[keep], origin=origin, scale=scale, **build_params)
    tree = dataclasses.replace(tree, tri_ids=keep[tree.tri_ids].astype(np.uint32),
                               n_input_tris=len(f))
    if keep_double:                     # by the whole mesh's ids, as tri_ids are
        tree = tree.with_double(v, f, built=True)
    log.debug("culled %d of %d triangles outside the view frustum", len(f) - len(keep), len(f))
    return tree, len(f) - len(keep)
