"""The public API: what `import kdray` exports, and that loading, building and the
reference tracer work on a machine without OpenCL or OpenImageIO."""
import subprocess
import sys

import kdray


def test_public_names():
    for name in ("load", "build", "Mesh", "KdTree", "BuildParams", "Tracer", "Hits", "Camera",
                 "Lidar", "KdrayError", "MeshError", "TreeFileError", "DeviceError", "KernelBuildError"):
        assert hasattr(kdray, name), name
    assert issubclass(kdray.KernelBuildError, kdray.DeviceError)
    assert issubclass(kdray.TreeFileError, kdray.KdrayError)


def test_no_opencl_or_oiio_needed_to_build():
    code = """
import sys
sys.modules["pyopencl"] = None          # any import of it now fails
sys.modules["OpenImageIO"] = None
import numpy as np, kdray
from kdray import reference
m = kdray.Mesh.from_arrays(np.random.default_rng(0).random((30, 3)), np.arange(30).reshape(10, 3))
tree = kdray.build(m.vertices, m.faces)
tree.validate()
h = reference.traverse(tree, np.zeros((5, 3)), np.ones((5, 3)))
print("ok", len(h.t))
"""
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True)
    assert out.returncode == 0, out.stderr
    assert out.stdout.strip() == "ok 5"


def test_no_public_name_means_two_things():
    # kdray.build is the function; the builder's modules are kdray.builder.*
    code = """
import kdray, kdray.builder, kdray.builder.prepare
assert callable(kdray.build) and kdray.build is kdray.builder.build
tree = kdray.builder.build([[0, 0, 0], [1, 0, 0], [0, 1, 0]], [[0, 1, 2]])
print(type(tree).__name__)
"""
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True)
    assert out.returncode == 0, out.stderr
    assert out.stdout.strip() == "KdTree"
    public = {name: getattr(kdray, name) for name in kdray.__all__}
    modules = {name for name, value in public.items() if type(value).__name__ == "module"}
    assert modules == {"cull"}


def test_builder_modules_are_not_shadowed():
    """Every module of kdray.builder is reachable under its own name: no function of the
    package carries a module's name."""
    import importlib
    import pkgutil
    import types
    import kdray.builder
    for info in pkgutil.iter_modules(kdray.builder.__path__):
        module = importlib.import_module(f"kdray.builder.{info.name}")
        assert isinstance(getattr(kdray.builder, info.name), types.ModuleType), info.name
        assert getattr(kdray.builder, info.name) is module


def test_a_tracer_is_not_pickled_but_its_tree_is():
    """Pickling (or deep-copying) a Tracer says to pickle its tree (pyopencl's "cannot
    pickle 'Context' object" before); copy.copy still shares it, as with_tree does."""
    import copy
    import pickle
    import numpy as np
    import pytest
    tracer = kdray.Tracer(kdray.build(np.eye(3), [[0, 1, 2]]))
    for call in (lambda: pickle.dumps(tracer), lambda: copy.deepcopy(tracer)):
        with pytest.raises(TypeError, match=r"pickle its tree \(Tracer.tree\)"):
            call()
    tree = pickle.loads(pickle.dumps(tracer.tree))
    o, d = np.array([[0.2, 0.2, -1.0]]), np.array([[0.0, 0.0, 1.0]])
    assert kdray.Tracer(tree).trace(o, d).t.tolist() == copy.copy(tracer).trace(o, d).t.tolist()
