"""The golden-image set: each shipped scene, its camera and the AOVs stored.

Used by tests/test_golden.py and regenerated on purpose by `make golden`."""
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
GOLDEN = Path(__file__).parent / "golden"
AOVS = ("depth", "distance", "normal", "bary", "id", "position")
WIDTH, HEIGHT = 96, 72


def cameras():
    """name -> (scene path, camera)."""
    from kdray.camera import Camera
    return {
        "cornell": (ROOT / "scenes" / "cornell.obj",
                    Camera.look_at((0.5, 0.5, 2.2), (0.5, 0.5, 0.5), (0, 1, 0), 40, WIDTH, HEIGHT)),
        "sphere": (ROOT / "scenes" / "sphere.obj",
                   Camera.look_at((1.7, 1.1, 2.3), (0, 0, 0), (0, 1, 0), 45, WIDTH, HEIGHT)),
        "quads": (ROOT / "scenes" / "quads.obj", None),   # the automatic framing camera
    }


def render(name, device=None):
    """Render one golden scene with every AOV; returns the images dict."""
    import kdray
    path, camera = cameras()[name]
    mesh = kdray.load(path)
    tree = kdray.build(mesh.vertices, mesh.faces)
    if camera is None:
        lo, hi = tree.world_box()
        camera = kdray.Camera.frame(lo, hi, WIDTH, HEIGHT)
    return kdray.Tracer(tree, device=device).render(camera, aovs=AOVS)
