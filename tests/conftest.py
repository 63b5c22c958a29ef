"""Shared fixtures: tiny generated scenes (tests never read ../shared)."""

from __future__ import annotations

import pytest

from nerfkit.data.npz import save_npz
from nerfkit.data.synthetic import sphere_scene


@pytest.fixture(scope="session")
def sphere():
    """20 training and 2 validation 32x32 views of a textured sphere."""
    return sphere_scene(n_train=20, n_val=2, size=32)


@pytest.fixture(scope="session")
def sphere_npz(tmp_path_factory, sphere):
    path = tmp_path_factory.mktemp("data") / "sphere.npz"
    save_npz(sphere, path)
    return path
