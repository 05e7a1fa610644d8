"""What a camera model costs against the plain pinhole: 1024 x 1024 renders of the bunny.

usage: python bench/bench_camera_models.py [--mesh bunny] [--size 1024] [--repeat 7]
                                           [--aovs depth,normal,id] [--device SPEC]

Cameras, all looking at the bunny from the framing camera's pose (Camera.frame, 45
degrees vertical): `pinhole` (rays made by the render kernel), `pinhole rays` (the same
pinhole's float64 rays from Camera.rays traced by Tracer.trace: the host path without
a lens), `opencv` (k1 k2 p1 p2 k3 = -0.28 0.07 8e-4 -1.1e-3 0.01: barrel distortion
with a tangential part), `opencv radial` (the same without p1 p2: no 2D Newton),
`fisheye` (k1..k4 = 0.08 -0.02 0.004 -5e-4, focal length for a 180-degree diagonal),
`orthographic` (the box's largest side across 90 % of the image; its rays do not
share an origin, so they are made on the host and traced by Tracer.trace).
Timed in turns (bench/timing.py round_robin), the median of --repeat rounds: the
whole Tracer.render call (each camera's ray map kept from the first call, as over the
views of a dataset: the render kernel turns the map by the pose, traces and the host
makes the images), and apart the lens's inversion alone (what the first view of a
camera's intrinsics adds). Prints Mrays/s and each camera's time over the pinhole's
(median of the per-round ratios). Then, for the opencv and fisheye cameras, how far
their renders' hit points land from the pixel centres when OpenCV projects them.
"""
import argparse
import math
import os
import sys

import numpy as np

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
from meshes import mesh as bench_mesh  # noqa: E402

import kdray  # noqa: E402
from kdray import Camera, lens  # noqa: E402
from timing import median_ratio, round_robin  # noqa: E402

OPENCV = (-0.28, 0.07, 8e-4, -1.1e-3, 0.01)
FISHEYE = (0.08, -0.02, 0.004, -5e-4)


def cameras(tree, size):
    lo, hi = tree.world_box()
    pinhole = Camera.frame(lo, hi, size, size)
    K, pose = pinhole.K, pinhole.cam_to_world
    f_fisheye = math.hypot(size / 2, size / 2) / (math.pi / 2)
    K_fisheye = np.array([[f_fisheye, 0, size / 2], [0, f_fisheye, size / 2], [0, 0, 1]])
    f_ortho = 0.9 * size / float(np.max(hi - lo))
    return {
        "pinhole": pinhole,
        "opencv": Camera(size, size, K, pose, "opencv", OPENCV),
        "opencv radial": Camera(size, size, K, pose, "opencv", OPENCV[:2] + (0.0, 0.0, OPENCV[4])),
        "fisheye": Camera(size, size, K_fisheye, pose, "fisheye", FISHEYE),
        # pixels per world unit: the box's largest side across 90 % of the image
        "orthographic": Camera(size, size, np.array([[f_ortho, 0, size / 2], [0, f_ortho, size / 2],
                                                     [0, 0, 1]]), pose, "orthographic"),
    }


def main(argv=None):
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--mesh", default="bunny")
    parser.add_argument("--size", type=int, default=1024)
    parser.add_argument("--repeat", type=int, default=7)
    parser.add_argument("--aovs", default="depth,normal,id")
    parser.add_argument("--device", default=None)
    args = parser.parse_args(argv)

    m = bench_mesh(args.mesh)
    tree = kdray.build(m.vertices, m.faces)
    tracer = kdray.Tracer(tree, device=args.device)
    cams = cameras(tree, args.size)
    n = args.size * args.size
    pinhole = cams["pinhole"]
    o, d = pinhole.rays()

    fns = {name: (lambda c=c: tracer.render(c, aovs=args.aovs)) for name, c in cams.items()}
    fns["pinhole rays"] = lambda: tracer.trace(pinhole.eye, d)
    for name, c in cams.items():
        if name != "pinhole":
            # the lens inverted, as the first view of these intrinsics does (later views
            # rotate the kept camera-axis map: what the renders above time)
            fns[f"{name}: rays"] = lambda c=c: lens._model_rays(c.model, c.K, c.distortion,
                                                                c.width, c.height)
    wall, _, results = round_robin(fns, args.repeat)

    print(f"{args.mesh} ({len(m.faces)} triangles), {args.size} x {args.size}, aovs "
          f"{args.aovs}, device {tracer.device.name.strip()}, median of {args.repeat} rounds")
    print(f"{'camera':<24}{'ms':>9}{'Mrays/s':>10}{'/ pinhole':>11}{'valid':>8}")
    for name in fns:
        if name.endswith(": rays"):
            continue
        ms = 1e3 * np.median(wall[name])
        ratio = median_ratio(wall[name], wall["pinhole"])
        images = results[name]
        valid = images["valid"].mean() if isinstance(images, dict) and "valid" in images else 1.0
        print(f"{name:<24}{ms:9.1f}{n / ms / 1e3:10.2f}{ratio:11.2f}{valid:8.3f}")
    print("the lens inverted (the first view of a camera's intrinsics; later views of the "
          "same intrinsics reuse it):")
    for name in cams:
        if name == "pinhole":
            continue
        rays, total = np.median(wall[f"{name}: rays"]), np.median(wall[name])
        print(f"  {name:<22}inversion {1e3 * rays:7.1f} ms against a render of {1e3 * total:7.1f} "
              f"ms: a first view takes about {1e3 * (rays + total):7.1f} ms "
              f"({(rays + total) / np.median(wall['pinhole']):.2f} x the pinhole)")

    reprojection(tracer, cams)


def reprojection(tracer, cams):
    """Print, for the opencv and fisheye cameras, how far the hit points of a render
    (float32 `position`) land from their pixel centres when OpenCV projects them
    (cv2.projectPoints / cv2.fisheye.projectPoints; points in front of the camera)."""
    try:
        import cv2
    except ImportError:
        print("reprojection: OpenCV not installed (opencv-python-headless)")
        return
    print("hit points projected by OpenCV, distance from their pixel centres (pixels):")
    for name, c in cams.items():
        if c.model not in ("opencv", "fisheye"):
            continue
        images = tracer.render(c, aovs="position,id")
        hit = images["id"].reshape(-1) != 0xFFFFFFFF
        p = images["position"].reshape(-1, 3)[hit].astype(np.float64)
        cam = (p - c.eye) @ c.rotation
        front = cam[:, 2] > 1e-3 * np.linalg.norm(cam, axis=1)
        R = c.rotation.T
        rvec, tvec, k = cv2.Rodrigues(R)[0], -R @ c.eye, np.array(c.distortion)
        obj = np.ascontiguousarray(p[front]).reshape(-1, 1, 3)
        if c.model == "fisheye":
            px = cv2.fisheye.projectPoints(obj, rvec, tvec, c.K, k)[0].reshape(-1, 2)
        else:
            px = cv2.projectPoints(obj, rvec, tvec, c.K, k)[0].reshape(-1, 2)
        j, i = np.divmod(np.flatnonzero(hit)[front], c.width)
        err = np.hypot(px[:, 0] - (i + 0.5), px[:, 1] - (j + 0.5))
        print(f"  {name:<22}max {err.max():.2e}, p99 {np.percentile(err, 99):.2e} "
              f"({len(err)} points)")


if __name__ == "__main__":
    main()
