"""Shared test set-up: strict JAX promotion rules and common fixtures."""

from __future__ import annotations

import sys
from pathlib import Path

import jax
import pytest

sys.path.insert(0, str(Path(__file__).resolve().parent))

# Catch accidental broadcasting of mismatched ranks inside the library.
jax.config.update("jax_numpy_rank_promotion", "raise")

from helpers import MESHES, SCENES  # noqa: E402


@pytest.fixture(scope="session")
def scenes_dir() -> Path:
    return SCENES


@pytest.fixture(scope="session")
def meshes_dir() -> Path:
    return MESHES


@pytest.fixture
def write_scene(tmp_path):
    """Write a scene TOML text to a file next to a copy-free mesh reference."""

    def _write(text: str, name: str = "scene.toml") -> Path:
        path = tmp_path / name
        path.write_text(text.replace("@MESHES@", str(MESHES)))
        return path

    return _write
