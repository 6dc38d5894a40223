"""calibrate — the Blender/Cycles reference renderer for jaxlc.

The main-environment side lives here and drives a worker process in the
separate ``.venv-blender`` environment (bpy 5.0 needs numpy<2, jax needs
numpy>=2; see ARCHITECTURE.md). :mod:`calibrate.environment` finds that
environment and says whether it is usable.
"""

from calibrate.environment import BlenderEnvironment, find_blender_environment

__all__ = ["BlenderEnvironment", "find_blender_environment"]
