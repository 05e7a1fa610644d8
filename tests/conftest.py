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
