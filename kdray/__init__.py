"""kdray: exact depth, normal, barycentric and triangle-id images of meshes.

    import kdray
    mesh = kdray.load("scene.obj")                  # vertices (n,3) float64, faces (m,3) int64
    tree = kdray.build(mesh.vertices, mesh.faces)   # SAH k-d tree (KdTree)
    tracer = kdray.Tracer(tree)                     # owns its OpenCL context
    hits = tracer.trace(origins, directions)        # t, prim, u, v, normal
    tracer.occluded(origins, directions)            # any hit; also count, contains,
    tracer.intersections(origins, directions)       # every hit (kdray.hit_lists)
    origins = kdray.offset_origins(tree, points, prim, directions)   # rays leaving a surface
    camera = kdray.Camera.look_at(eye, target)
    images = tracer.render(camera, aovs=("depth", "id"))
    scan = tracer.scan(kdray.Lidar.from_json("lidar.json"), sensor_to_world)  # range image
    tree, n_left_out = kdray.cull.build_for_camera(mesh.vertices, mesh.faces, camera)  # seen part

The public API is what this module exports, nothing else.
"""
# First: OpenCL runtimes installed with pip become visible to pyopencl's loader before
# anything lists platforms; Intel's runtime as kdray's copy with a TBB of its own, which
# loads whatever was imported before (Open3D's older TBB: kdray.runtimes says why).
from .runtimes import register_runtimes as _register_runtimes

_register_runtimes()

from . import cull
from .builder import build
from .camera import Camera
from .lidar import Lidar
from .errors import (CameraError, DatasetError, DeviceError, KdrayError, KernelBuildError,
                     MeshError, OutputError, ParameterError, TreeError, TreeFileError)
from .load import load
from .mesh import Mesh
from .hit_lists import Intersections
from .points import ClosestPoints
from .spawn import offset_origins
from .hits import Hits
from .trace import Tracer
from .tree import BuildParams, KdTree

__version__ = "0.1.0"

__all__ = ["load", "build", "cull", "Mesh", "KdTree", "BuildParams", "Tracer", "Hits", "Intersections", "ClosestPoints", "offset_origins", "Camera", "Lidar",
           "KdrayError", "MeshError", "TreeError", "TreeFileError", "DeviceError",
           "KernelBuildError", "CameraError", "OutputError", "ParameterError", "DatasetError"]
