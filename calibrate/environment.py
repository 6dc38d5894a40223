"""Locate the Blender worker environment (``.venv-blender``) without importing bpy."""

from __future__ import annotations

import dataclasses
import os
from pathlib import Path

#: The checkout's root (``calibrate/`` lives directly under it).
REPO_ROOT = Path(__file__).resolve().parent.parent


@dataclasses.dataclass(frozen=True)
class BlenderEnvironment:
    """Where the worker environment is and what it holds.

    Attributes:
        root: the virtual environment's folder.
        python: its interpreter (exists only if the environment was built).
        bpy_version: version of the installed ``bpy`` wheel, or None.
    """

    root: Path
    python: Path
    bpy_version: str | None

    @property
    def available(self) -> bool:
        return self.python.is_file() and self.bpy_version is not None

    def describe(self) -> str:
        if self.available:
            return f"bpy {self.bpy_version} in {self.root}"
        if self.python.is_file():
            return f"{self.root} exists but has no bpy; run `make setup`"
        return f"not built ({self.root}); run `make setup`"


def find_blender_environment() -> BlenderEnvironment:
    """The worker environment: ``$JAXLC_BLENDER_VENV`` or ``<checkout>/.venv-blender``.

    Reads the installed ``bpy`` version from its ``dist-info`` folder, so this
    is instant (importing bpy takes seconds).
    """
    root = Path(os.environ.get("JAXLC_BLENDER_VENV", REPO_ROOT / ".venv-blender"))
    python = root / "bin" / "python"
    version = None
    for info in sorted(root.glob("lib/python3*/site-packages/bpy-*.dist-info")):
        version = info.name.removeprefix("bpy-").removesuffix(".dist-info")
    return BlenderEnvironment(root=root, python=python, bpy_version=version)
