"""jaxlc — fast, checkable light curves of resident space objects.

The front door, one name per stage of the pipeline::

    import jaxlc
    geometry = jaxlc.geometry_table(tle, site, start_utc, 1200)    # or synthetic_geometry(...)
    lc = jaxlc.render("s4_falcon9", geometry)                      # light-curve table
    period = jaxlc.analyse_period(lc.t_s, lc.mag)                  # spin period, or "not variable"
    fit = jaxlc.fit_spin(jaxlc.load_scene("s4_falcon9"), lc, geometry)
    ds = jaxlc.generate("config.toml", "bulk.zarr")                # labelled datasets

Subpackages follow the data flow: :mod:`jaxlc.geometry` (TLE → geometry
table) → :mod:`jaxlc.body` (mesh, materials, attitude, self-shadowing) →
:mod:`jaxlc.rendering` (prepare, plan, blur, kernel, render) →
:mod:`jaxlc.inference` and :mod:`jaxlc.dataset`, with :mod:`jaxlc.io` (tables,
strict TOML, atomic files, the cache) and :mod:`jaxlc.cli` at the edges.
Every path that makes a light curve calls one preparation
(:func:`prepare`) and one kernel entry (:func:`exposure_intensity`).
"""

from jaxlc.io.provenance import jaxlc_version

__version__ = jaxlc_version()  # "0+unknown" in a source tree without install

from jaxlc.body.attitude import AbstractAttitude, Fixed, Spin
from jaxlc.body.brdf import AbstractBRDF, ASGlossy, AshikhminShirley, Lambert
from jaxlc.body.facet_model import FacetModel, facet_model
from jaxlc.body.mesh import Facets, TriangleMesh, facets_from_mesh, load_mesh
from jaxlc.body.tumble import Tumble
from jaxlc.dataset import generate, load_config, open_dataset
from jaxlc.errors import JaxlcError, MeshError, SceneError, TableError
from jaxlc.geometry import find_passes, geometry_table, get_site, read_tles, synthetic_geometry
from jaxlc.inference import FitSettings, analyse_period, fit_spin
from jaxlc.io.observations import read_observations
from jaxlc.io.tables import (
    read_geometry,
    read_lightcurve,
    read_table,
    validate_geometry,
    write_table,
)
from jaxlc.rendering.exposures import Exposures, exposure_instants
from jaxlc.rendering.kernel import (
    KernelInputs,
    SpaceObject,
    exposure_intensity,
    light_curve_intensity,
    stack_objects,
)
from jaxlc.rendering.observation import GeometryArrays, geometry_arrays, geometry_from_positions
from jaxlc.rendering.options import RenderOptions
from jaxlc.rendering.prepare import (
    Prepared,
    kernel_inputs,
    prepare,
    rotation_matrices,
    space_object,
)
from jaxlc.rendering.render import lightcurve_table, render
from jaxlc.scene import Scene, load_scene, scene_from_dict, scene_path

__all__ = [
    "ASGlossy",
    "AbstractAttitude",
    "AbstractBRDF",
    "AshikhminShirley",
    "Exposures",
    "FacetModel",
    "Facets",
    "FitSettings",
    "Fixed",
    "GeometryArrays",
    "JaxlcError",
    "KernelInputs",
    "Lambert",
    "MeshError",
    "Prepared",
    "RenderOptions",
    "Scene",
    "SceneError",
    "SpaceObject",
    "Spin",
    "TableError",
    "TriangleMesh",
    "Tumble",
    "__version__",
    "analyse_period",
    "exposure_instants",
    "exposure_intensity",
    "facet_model",
    "facets_from_mesh",
    "find_passes",
    "fit_spin",
    "generate",
    "geometry_arrays",
    "geometry_from_positions",
    "geometry_table",
    "get_site",
    "kernel_inputs",
    "light_curve_intensity",
    "lightcurve_table",
    "load_config",
    "load_mesh",
    "load_scene",
    "open_dataset",
    "prepare",
    "read_geometry",
    "read_lightcurve",
    "read_observations",
    "read_table",
    "read_tles",
    "render",
    "rotation_matrices",
    "scene_from_dict",
    "scene_path",
    "space_object",
    "stack_objects",
    "synthetic_geometry",
    "validate_geometry",
    "write_table",
]
