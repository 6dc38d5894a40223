"""jaxlc — fast, checkable light curves of resident space objects.

The front door::

    import jaxlc
    scene = jaxlc.load_scene("experiments/scenes/s4_falcon9.toml")
    geometry = jaxlc.synthetic_geometry(duration_s=1200, phase_start_deg=20, phase_end_deg=120)
    lc = jaxlc.render(scene, geometry)          # a pandas DataFrame (light-curve table)

Lower layers (pure JAX, jittable, differentiable, vmappable): :mod:`jaxlc.brdf`,
:mod:`jaxlc.attitude`, :func:`jaxlc.render.light_curve_intensity`.
"""

from importlib import metadata as _metadata

try:
    __version__ = _metadata.version("jaxlc")
except _metadata.PackageNotFoundError:  # running from a source tree without install
    __version__ = "0+unknown"

from jaxlc.attitude import AbstractAttitude, Fixed, Spin
from jaxlc.brdf import AbstractBRDF, ASGlossy, AshikhminShirley, FacetModel, Lambert, facet_model
from jaxlc.errors import JaxlcError, MeshError, SceneError, TableError
from jaxlc.geometry import synthetic_geometry
from jaxlc.mesh import Facets, TriangleMesh, facets_from_mesh, load_mesh
from jaxlc.render import SpaceObject, light_curve_intensity, render, space_object, stack_objects
from jaxlc.scene import Scene, load_scene, scene_from_dict
from jaxlc.tables import read_geometry, read_lightcurve, read_table, write_table

__all__ = [
    "ASGlossy",
    "AbstractAttitude",
    "AbstractBRDF",
    "AshikhminShirley",
    "FacetModel",
    "Facets",
    "Fixed",
    "JaxlcError",
    "Lambert",
    "MeshError",
    "Scene",
    "SceneError",
    "SpaceObject",
    "Spin",
    "TableError",
    "TriangleMesh",
    "__version__",
    "facet_model",
    "facets_from_mesh",
    "light_curve_intensity",
    "load_mesh",
    "load_scene",
    "read_geometry",
    "read_lightcurve",
    "read_table",
    "render",
    "scene_from_dict",
    "space_object",
    "stack_objects",
    "synthetic_geometry",
    "write_table",
]
