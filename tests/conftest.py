"""Shared fixtures: paths to the shared meshes and the project's scenes."""
from pathlib import Path

import numpy as np
import pytest

ROOT = Path(__file__).resolve().parents[1]
SHARED_MESHES = ROOT.parent / "shared" / "meshes"
SCENES = ROOT / "scenes"


def shared_mesh(name):
    path = SHARED_MESHES / name
    if not path.exists():
        pytest.skip(f"shared mesh {path} is not present")
    return path


@pytest.fixture
def rng():
    return np.random.default_rng(12345)


def shared_mesh_arrays(name):
    """(vertices (n,3) float64, faces (m,3) int64) of a shared mesh, loaded by kdray.load;
    the test is skipped when ../shared/meshes is absent."""
    from kdray.load import load
    m = load(shared_mesh(name))
    return m.vertices, m.faces
