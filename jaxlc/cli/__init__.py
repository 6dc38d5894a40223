"""The ``jaxlc`` command line (``jaxlc --help``; ``python -m jaxlc.cli``).

:mod:`jaxlc.cli.app` holds the application and the entry point :func:`main`;
importing this package registers every command group on it.
"""

from jaxlc.cli import calibrate, dataset, geometry, imaging, inference, render
from jaxlc.cli.app import app, main

__all__ = ["app", "calibrate", "dataset", "geometry", "imaging", "inference", "main", "render"]
