"""What the seed paper's reproductions share: the demo pass, the seed's spin set-up,
body-frame view directions, provenance and where results go.

The scripts of this folder import it as ``paper.common`` (``experiments/`` on
``sys.path``); ``make paper`` runs them all.
"""

from __future__ import annotations

import dataclasses
from pathlib import Path

import numpy as np
import pandas as pd
from run_info import provenance as run_provenance

import jaxlc
from jaxlc.geometry.observe import geometry_table
from jaxlc.geometry.sites import get_site
from jaxlc.geometry.tle import read_tles

EXPERIMENTS = Path(__file__).resolve().parents[1]
REPO = EXPERIMENTS.parent
RESULTS = EXPERIMENTS / "results" / "paper"
TLE = REPO / "data" / "tle" / "falcon9_rb.tle"

#: The seed's spin period of Falcon 9 R/B 40108 (s): twice its Lomb–Scargle peak.
SEED_PERIOD_S = 82.6
#: The seed's Blender set-up spins a model about its own x or y axis, the body
#: axes starting along the world (here GCRS) axes: the pole is that world axis.
SEED_POLES_DEG = {"x": (0.0, 0.0), "y": (90.0, 0.0)}


#: Start of the ``make demo`` pass (phase angle 117–119°, range 36,000–38,000 km).
DEMO_START_UTC = "2020-08-10T18:00:00Z"
#: A pass of the same object a day later, soon after perigee: phase angle 10–60°
#: and range 6,200–9,900 km in 20 minutes (the seed's Fig. 4 pass brightened as its
#: phase angle fell; this one dims as it rises).
PHASE_SWEEP_START_UTC = "2020-08-11T19:02:00Z"


def demo_pass(duration_s: float = 1200.0, start_utc: str = DEMO_START_UTC) -> pd.DataFrame:
    """Geometry of Falcon 9 R/B 45921 from Mt Stromlo, 1 s samples and exposures
    (by default the ``make demo`` pass)."""
    tle = next(t for t in read_tles(TLE) if t.norad_id == 45921)
    start = pd.Timestamp(start_utc)
    return geometry_table(tle, get_site("mt-stromlo"), start, duration_s, 1.0, 1.0)


def seed_spin(scene: jaxlc.Scene, axis: str, period_s: float = SEED_PERIOD_S) -> jaxlc.Scene:
    """``scene`` spinning about body ``axis`` ("x" or "y") as the seed's Blender
    models did: pole along that GCRS axis, phase 0 at the first sample."""
    ra, dec = SEED_POLES_DEG[axis]
    body_axis = (1.0, 0.0, 0.0) if axis == "x" else (0.0, 1.0, 0.0)
    spin = dataclasses.replace(
        scene.attitude,
        model="spin",
        body_axis=body_axis,
        pole_ra_deg=ra,
        pole_dec_deg=dec,
        period_s=float(period_s),
        phase_deg=0.0,
        epoch_utc=None,
    )
    return dataclasses.replace(scene, attitude=spin)


def observer_in_body(scene: jaxlc.Scene, geometry: pd.DataFrame) -> np.ndarray:
    """(N, 3) unit object → observer direction in the body frame at each row's
    mid-exposure (NaN for rows that are not rendered), from the renderer's own
    preparation."""
    from calibrate.visibility import body_directions

    plain = jaxlc.RenderOptions(shadows="off", blur="off")
    p = jaxlc.prepare(scene, geometry, plain, precision="float64", subsamples=1)
    out = np.full((len(geometry), 3), np.nan)
    out[np.asarray(p.exposures.rows)] = body_directions(p)[1]
    return out


def provenance(script: str, **extra) -> dict[str, str]:
    """Attributes every result table carries (:func:`run_info.provenance`)."""
    return run_provenance(f"experiments/paper/{script}", **extra)


def write_result(table: pd.DataFrame, path: Path, **attrs) -> Path:
    """Write ``table`` atomically as CSV with its provenance; returns the path."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    table.attrs.update(attrs)
    return jaxlc.write_table(table, path)


def save_png(fig, path: Path, dpi: int = 70) -> Path:
    """Save a figure atomically as a PNG of 256 colours (a third of the size; these
    figures are committed), and close it."""
    from jaxlc.plot import save_figure

    save_figure(fig, path, dpi=dpi)
    return quantize_png(path)


def quantize_png(path: Path) -> Path:
    """Rewrite a PNG atomically with 256 colours (a third of the size)."""
    from PIL import Image

    from jaxlc.io.files import atomic_output

    with Image.open(path) as im:
        small = im.convert("RGB").quantize(256)
    with atomic_output(Path(path)) as tmp:
        small.save(tmp, format="PNG", optimize=True)
    return Path(path)


def pyplot():
    """matplotlib's pyplot on the Agg backend (no display needed)."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    return plt
