"""Spin-state inference: periods of observed light curves and spin fits.

* :mod:`jaxlc.inference.period` — Lomb–Scargle period analysis
  (:func:`analyse_period`);
* :mod:`jaxlc.inference.data` — observed samples paired with their geometry;
* :mod:`jaxlc.inference.model` — the forward model: the renderer's prepared
  object and exposures with the spin as parameters;
* :mod:`jaxlc.inference.search` — multi-start Levenberg–Marquardt (optimistix);
* :mod:`jaxlc.inference.mcmc` — emcee around the modes;
* :mod:`jaxlc.inference.fit` — the whole fit and its outputs (:func:`fit_spin`).
"""

from jaxlc.inference.fit import FitSettings, fit_spin
from jaxlc.inference.period import analyse_period
from jaxlc.inference.period_result import PeriodResult

__all__ = ["FitSettings", "PeriodResult", "analyse_period", "fit_spin"]
