"""Rendering: scene + geometry → light curve, through one preparation and one kernel.

* :mod:`~jaxlc.rendering.observation` — per-row geometry (directions, range,
  irradiance, phase angle) of a geometry table;
* :mod:`~jaxlc.rendering.options`, :mod:`~jaxlc.rendering.plan`,
  :mod:`~jaxlc.rendering.blur` — what a render does (shadows, sub-exposures,
  rows) and why;
* :mod:`~jaxlc.rendering.exposures` — the instants of each exposure and
  their quadrature weights;
* :mod:`~jaxlc.rendering.prepare` — **the** preparation every path calls;
* :mod:`~jaxlc.rendering.kernel` — **the** kernel entry
  (:func:`~jaxlc.rendering.kernel.exposure_intensity`);
* :mod:`~jaxlc.rendering.photometry` — I/E → flux → magnitude (float64);
* :mod:`~jaxlc.rendering.render` — the front door, :func:`jaxlc.render`.
"""
