from __future__ import annotations

import numpy as np
import pytest
import trimesh

from scenes.sampling import sample_surface


@pytest.fixture(scope="session")
def torus_mesh() -> trimesh.Trimesh:
    return trimesh.creation.torus(major_radius=0.08, minor_radius=0.03, major_sections=96, minor_sections=48)


@pytest.fixture(scope="session")
def torus_cloud(torus_mesh):
    return sample_surface(torus_mesh, 40_000, seed=7)


def rng(seed: int = 0) -> np.random.Generator:
    return np.random.default_rng(seed)
