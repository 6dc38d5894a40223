"""Bulk datasets: config strictness, determinism, resuming, labels against a re-render.

Every check recomputes independently: curves are re-rendered with
:func:`jaxlc.render` from their label columns and geometry rebuilt with
:func:`jaxlc.synthetic_geometry` / :func:`geometry_table`; the noise error is
recomputed from its formula; stores are compared byte for byte.
"""

from __future__ import annotations

import json
import math
import os
import re
import signal
import subprocess
import sys
import time
import tomllib

import numpy as np
import pytest
from helpers import MESHES, REPO, SCENES

import jaxlc
import jaxlc.dataset as dataset
from jaxlc.dataset import DatasetError, config_from_dict, load_config
from jaxlc.rendering import photometry

pytest.importorskip("zarr")

CONFIG = f"""
[dataset]
count = 18
samples = 96
shard_size = 4
seed = 11
batch_size = 8

[[class]]
name = "cylinder"
scene = "{SCENES / "s3_cylinder.toml"}"
scale = [0.5, 2.0]
period_s = [10.0, 100.0]
[[class.material]]
brdf = "ashikhmin-shirley"
rd = [0.3, 0.8]
rs = [0.05, 0.3]
nu = [5.0, 200.0]

[[class]]
name = "boxwing"
scene = "{SCENES / "s6_boxwing.toml"}"
scale = [0.5, 2.0]
period_s = [20.0, 300.0]

[[class]]
name = "cubesat"
mesh = "{MESHES / "cubesat_3u.obj"}"
body_axis = [1, 0, 0]
period_s = [5.0, 30.0]
[[class.material]]
brdf = "ashikhmin-shirley"
rd = 0.2
rs = [0.2, 0.5]
nu = [200.0, 1000.0]

[geometry]
source = "synthetic"
phase_start_deg = [10.0, 90.0]
phase_end_deg = [30.0, 150.0]
range_start_m = [5.0e5, 3.0e6]
range_end_m = [5.0e5, 3.0e6]

[noise]
zero_point_mag = 18.0
sky_e_per_s = 300.0
read_noise_e = 10.0
aperture_m = 0.3
airmass = 1.5
altitude_m = 800.0
"""

ARRAYS = ("mag", "flux_w_m2", "phase_angle_deg", "range_m", "visible")
NOISY = ("mag_noisy", "flux_noisy_w_m2", "mag_err")


@pytest.fixture(scope="module")
def config_path(tmp_path_factory):
    path = tmp_path_factory.mktemp("cfg") / "bulk.toml"
    path.write_text(CONFIG)
    return path


@pytest.fixture(scope="module")
def reference(config_path, tmp_path_factory):
    """The dataset rendered in this process, shard after shard (the reference)."""
    out = tmp_path_factory.mktemp("ref") / "ref.zarr"
    return dataset.generate(config_path, out, workers=0, progress=False)


def same_bytes(a, b) -> None:
    """Every array and label of two stores is identical, byte for byte."""
    for name in (*ARRAYS, *NOISY):
        x, y = np.asarray(a[name][...]), np.asarray(b[name][...])
        assert x.dtype == y.dtype and x.tobytes() == y.tobytes(), name
    assert a.labels.equals(b.labels)


# ---------------------------------------------------------------------------
# Config


def _config_dict():
    return tomllib.loads(CONFIG)


@pytest.mark.parametrize(
    ("edit", "needles"),
    [
        (lambda d: d["dataset"].update(shardsize=3), ["[dataset]", "shardsize", "shard_size"]),
        (lambda d: d["class"][0].update(period_s=[100.0, 10.0]), ["period_s", "[100.0, 10.0]"]),
        (lambda d: d["class"][0].update(scale=[-1.0, 2.0]), ["scale", "[-1.0, 2.0]"]),
        (lambda d: d["class"][0]["material"][0].update(rd=[0.5, 1.5]), ["rd", "[0.5, 1.5]"]),
        (lambda d: d["geometry"].update(phase_end_deg=[30, 200]), ["phase_end_deg", "200"]),
        (lambda d: d["class"][2].update(mesh="meshes/nope.obj"), ["mesh", "meshes/nope.obj"]),
        (lambda d: d["class"][1].update(scene="nope.toml"), ["scene", "nope.toml"]),
        (lambda d: d["dataset"].pop("seed"), ["[dataset]", "seed"]),
        (lambda d: d["dataset"].update(count=2.5), ["count", "2.5"]),
        (lambda d: d["class"][0]["material"][0].update(part="wing"), ["part", "wing"]),
        (lambda d: d["class"][2].pop("body_axis"), ["body_axis"]),
        (lambda d: d["geometry"].update(source="orbit"), ["source", "orbit"]),
        (lambda d: d["noise"].update(gain=2.0), ["[noise]", "gain"]),
        (lambda d: d["class"][1].update(name="cylinder"), ["name", "cylinder"]),
    ],
)
def test_config_errors_name_key_and_value(edit, needles):
    data = _config_dict()
    edit(data)
    with pytest.raises(DatasetError) as err:
        config_from_dict(data, source="bulk.toml")
    message = str(err.value)
    assert "bulk.toml" in message
    for needle in needles:
        assert needle in message, message


def test_config_file_errors(tmp_path):
    with pytest.raises(DatasetError, match="does not exist"):
        load_config(tmp_path / "missing.toml")
    bad = tmp_path / "bad.toml"
    bad.write_text("[dataset\ncount = 1")
    with pytest.raises(DatasetError, match="not valid TOML"):
        load_config(bad)


def test_passes_config_errors():
    data = _config_dict()
    data["geometry"] = {
        "source": "passes",
        "tle": str(REPO / "data" / "tle" / "falcon9_rb.tle"),
        "sites": ["atlantis"],
        "start_utc": "2020-08-09T00:00:00Z",
        "days": 1,
    }
    del data["noise"]
    with pytest.raises(DatasetError, match=r"sites.*atlantis"):
        config_from_dict(data, source="bulk.toml")
    data["geometry"]["sites"] = ["mt-stromlo"]
    data["noise"] = {"zero_point_mag": 20.0, "airmass": 1.2}
    with pytest.raises(DatasetError, match="airmass"):
        config_from_dict(data, source="bulk.toml")


# ---------------------------------------------------------------------------
# Determinism


def test_curves_and_shards_are_pure_functions(config_path, reference):
    from jaxlc.dataset.shards import render_shard

    cfg = load_config(config_path)
    fewer = dataclasses_replace(cfg, count=5)
    assert dataset.draw_curve(cfg, 3) == dataset.draw_curve(fewer, 3)  # independent of count
    assert dataset.draw_curve(cfg, 3) != dataset.draw_curve(cfg, 4)
    # Shards in another order, in this process: the same bytes as the stored ones.
    for k in (3, 1, 4):
        shard = render_shard(cfg, k)
        rows = cfg.shard_rows(k)
        for name in (*ARRAYS, *NOISY):
            stored = np.asarray(reference[name][rows.start : rows.stop])
            assert shard.arrays[name].tobytes() == stored.tobytes(), (k, name)


def dataclasses_replace(obj, **kw):
    import dataclasses

    return dataclasses.replace(obj, **kw)


def test_same_bytes_with_two_dask_workers(config_path, reference, tmp_path):
    pytest.importorskip("distributed")
    ds = dataset.generate(config_path, tmp_path / "dask.zarr", workers=2, progress=False)
    same_bytes(ds, reference)
    assert ds.attrs["fingerprint"] == reference.attrs["fingerprint"]
    assert ds.attrs["config_text"] == CONFIG
    assert ds.attrs["jaxlc_version"] == jaxlc.__version__


@pytest.mark.skipif(
    not hasattr(os, "sched_getaffinity") or not 2 <= len(os.sched_getaffinity(0)) <= 4,
    reason="pins workers that fill 2-4 cores (Linux)",
)
def test_local_workers_that_fill_the_cores_get_one_core_each(monkeypatch):
    """Pinned workers, and no glibc malloc setting from Dask's nanny (it fixes the mmap
    threshold, and every large array is then faulted in afresh) unless the user set one."""
    pytest.importorskip("distributed")
    import dask

    from jaxlc.dataset import local_cluster, runner

    trim = local_cluster.MALLOC_TRIM_ENV
    monkeypatch.delenv(trim, raising=False)
    n = len(os.sched_getaffinity(0))
    with runner.dask_client(n, None, n) as client:
        pinned = client.run(os.sched_getaffinity, 0)
        malloc = client.run(os.environ.get, trim)
        profiler = client.run(lambda: dask.config.get("distributed.worker.profile.enabled"))
    assert sorted(len(c) for c in pinned.values()) == [1] * n
    assert set().union(*pinned.values()) == set(os.sched_getaffinity(0))
    assert list(malloc.values()) == [None] * n
    assert list(profiler.values()) == [False] * n  # local_cluster.QUIET_CONFIG reached them
    monkeypatch.setenv(local_cluster.PIN_WORKERS_ENV, "off")
    monkeypatch.setenv(trim, "1048576")  # the user's own: kept
    with runner.dask_client(n, None, n) as client:
        free = client.run(os.sched_getaffinity, 0)
        malloc = client.run(os.environ.get, trim)
    assert all(c == os.sched_getaffinity(0) for c in free.values())
    assert list(malloc.values()) == ["1048576"] * n


# ---------------------------------------------------------------------------
# Resuming


def test_interrupted_run_resumes_without_loss(config_path, reference, tmp_path):
    out = tmp_path / "resume.zarr"
    first = []

    def stop_after_two(k):
        first.append(k)
        if len(first) == 2:
            raise KeyboardInterrupt

    with pytest.raises(KeyboardInterrupt):
        dataset.generate(config_path, out, workers=0, progress=False, on_shard=stop_after_two)
    with pytest.raises(DatasetError, match=r"incomplete: 2 of 5 shards.*partial=True"):
        dataset.open(out)
    part = dataset.open(out, partial=True)
    assert list(part.labels.index) == list(range(8))
    assert part.load("mag").shape == (8, 96)

    # A shard killed half-way: new data in some chunks, never marked done.
    import zarr

    root = zarr.open_group(str(out), mode="r+")
    root["mag"][12:16] = np.float32(99.0)
    root["labels"]["period_s"][12:16] = -1.0

    second = []
    ds = dataset.generate(config_path, out, workers=0, progress=False, on_shard=second.append)
    assert sorted(second) == [2, 3, 4]  # only the missing shards were rendered
    assert list(ds.labels.index) == list(range(18))  # no curve missing or twice
    same_bytes(ds, reference)


def test_store_without_a_newer_label_resumes(config_path, reference, tmp_path):
    """A store begun before a label column existed (here: instants_per_exposure, deleted)
    is resumed: its finished shards read the column's fill, the new shards write it."""
    import zarr

    out = tmp_path / "older.zarr"
    first = []

    def stop_after_one(k):
        first.append(k)
        raise KeyboardInterrupt

    with pytest.raises(KeyboardInterrupt):
        dataset.generate(config_path, out, workers=0, progress=False, on_shard=stop_after_one)
    del zarr.open_group(str(out), mode="r+")["labels"]["instants_per_exposure"]
    ds = dataset.generate(config_path, out, workers=0, progress=False)
    got = ds.labels["instants_per_exposure"].to_numpy()
    want = reference.labels["instants_per_exposure"].to_numpy()
    assert np.all(np.isnan(got[:4]))  # the shard finished before: the column's fill
    np.testing.assert_array_equal(got[4:], want[4:])
    assert np.all(want[reference.labels["visible_samples"].to_numpy() > 0] >= 1)


def test_a_store_with_an_older_codec_resumes_to_the_same_values(
    config_path, reference, tmp_path, monkeypatch
):
    """A store begun with zarr's default codec (Zstandard, as before store.ARRAY_CODEC)
    is resumed in its own codec, and reads back the values of a store made today."""
    import zarr

    out = tmp_path / "zstd.zarr"
    monkeypatch.setattr(zarr.codecs, "BloscCodec", lambda **_: zarr.codecs.ZstdCodec(level=0))

    def stop_after_one(k):
        raise KeyboardInterrupt

    with pytest.raises(KeyboardInterrupt):
        dataset.generate(config_path, out, workers=0, progress=False, on_shard=stop_after_one)
    monkeypatch.undo()
    ds = dataset.generate(config_path, out, workers=0, progress=False)
    codec = zarr.open_group(str(out), mode="r")["mag"].compressors
    assert [type(c).__name__ for c in codec] == ["ZstdCodec"]
    ref_codec = zarr.open_group(str(reference.path), mode="r")["mag"].compressors
    assert [type(c).__name__ for c in ref_codec] == ["BloscCodec"]
    same_bytes(ds, reference)


def test_workers_from_a_script_on_stdin_are_refused_with_the_fix(
    config_path, tmp_path, monkeypatch
):
    """Worker processes re-import the caller's main module, which a script read from
    stdin does not have: one clear error before anything is written, not Dask's
    traceback of a nanny that failed to start."""
    import sys
    import types

    main = types.ModuleType("__main__")
    main.__file__ = "<stdin>"
    monkeypatch.setitem(sys.modules, "__main__", main)
    out = tmp_path / "stdin.zarr"
    with pytest.raises(DatasetError, match=r"read from '<stdin>'.*file.*workers = 0"):
        dataset.generate(config_path, out, workers=2, progress=False)
    assert not out.exists()


def test_a_store_made_again_at_its_path_is_written_anew(config_path, tmp_path):
    """write_shard keeps each store's opened arrays for the next shard; a store removed and
    made again at the same path (another count and seed) must not be written through the
    old one's arrays: same bytes as at a path never used."""
    import shutil

    out = tmp_path / "again.zarr"
    dataset.generate(config_path, out, workers=0, count=8, progress=False)
    shutil.rmtree(out)
    again = dataset.generate(config_path, out, workers=0, count=12, seed=5, progress=False)
    fresh = dataset.generate(
        config_path, tmp_path / "fresh.zarr", workers=0, count=12, seed=5, progress=False
    )
    assert int(again.done.sum()) == len(again.done) and len(again.labels) == 12
    same_bytes(again, fresh)


def test_killed_process_resumes_to_the_uninterrupted_result(tmp_path):
    cfg = tmp_path / "kill.toml"
    cfg.write_text(
        CONFIG.replace(
            "count = 18\nsamples = 96\nshard_size = 4", "count = 48\nsamples = 48\nshard_size = 2"
        )
    )
    out = tmp_path / "killed.zarr"
    proc = subprocess.Popen(
        [sys.executable, "-m", "jaxlc.cli", "generate", str(cfg), "-o", str(out), "--workers", "0"],
        stdout=subprocess.DEVNULL,
        stderr=subprocess.DEVNULL,
    )
    marks = out / "shards" / "done" / "c"
    try:
        deadline = time.monotonic() + 120
        while not (marks.is_dir() and any(marks.iterdir())):
            assert proc.poll() is None, "generate ended before the first shard"
            assert time.monotonic() < deadline
            time.sleep(0.01)
    finally:
        proc.send_signal(signal.SIGKILL)
        proc.wait()
    done = int(dataset.open(out, partial=True).done.sum())
    assert 1 <= done < 24  # killed part-way
    resumed = dataset.generate(cfg, out, workers=0, progress=False)
    assert list(resumed.labels.index) == list(range(48))
    whole = dataset.generate(cfg, tmp_path / "whole.zarr", workers=0, progress=False)
    same_bytes(resumed, whole)


def test_other_config_refuses_to_resume(config_path, reference, tmp_path):
    with pytest.raises(DatasetError, match="different config"):
        dataset.generate(config_path, reference.path, workers=0, seed=12, progress=False)
    (tmp_path / "junk.zarr").mkdir()
    with pytest.raises(DatasetError, match="not a"):
        dataset.generate(config_path, tmp_path / "junk.zarr", workers=0, progress=False)
    with pytest.raises(DatasetError, match="does not exist"):
        dataset.open(tmp_path / "nothing.zarr")

    # A store of the first format (zero-flux samples marked visible): read with a warning,
    # never resumed.
    import shutil

    import zarr

    old = tmp_path / "old.zarr"
    shutil.copytree(reference.path, old)
    zarr.open_group(str(old), mode="r+").attrs["format"] = "jaxlc-dataset/1"
    with pytest.warns(UserWarning, match=r"older jaxlc.*visible & np.isfinite\(mag\)"):
        assert len(dataset.open(old)) == 18
    with pytest.raises(DatasetError, match=r"older jaxlc.*cannot be resumed"):
        dataset.generate(config_path, old, workers=0, progress=False)


# ---------------------------------------------------------------------------
# Labels against an independent re-render


def _scene_from_labels(ds, i):
    """A scene dict written from the label columns (not with Dataset.scene)."""
    row = ds.labels.loc[i]
    cls = ds.attrs["classes"][int(row["class_id"])]
    return {
        "object": {"mesh": row["mesh"], "scale": float(row["scale"])},
        "material": json.loads(row["materials"]),
        "attitude": {
            "model": "spin",
            "body_axis": [
                float(row["body_axis_x"]),
                float(row["body_axis_y"]),
                float(row["body_axis_z"]),
            ],
            "pole_ra_deg": float(row["pole_ra_deg"]),
            "pole_dec_deg": float(row["pole_dec_deg"]),
            "period_s": float(row["period_s"]),
            "phase_deg": float(row["phase_deg"]),
        },
        "render": dict(cls["render"]),
    }


def _synthetic_from_labels(ds, i):
    row = ds.labels.loc[i]
    n = int(ds.attrs["samples"])
    return jaxlc.synthetic_geometry(
        duration_s=n * float(ds.attrs["cadence_s"]),
        step_s=float(ds.attrs["cadence_s"]),
        phase_start_deg=float(row["phase_start_deg"]),
        phase_end_deg=float(row["phase_end_deg"]),
        range_start_m=float(row["range_start_m"]),
        range_end_m=float(row["range_end_m"]),
        exposure_s=float(ds.attrs["exposure_s"]),
        start_utc=row["utc_start"],
        sun_ra_deg=float(row["sun_ra_deg"]),
        sun_dec_deg=float(row["sun_dec_deg"]),
        tilt_deg=float(row["tilt_deg"]),
    )


def _same_as_render(ds, i, lc) -> np.ndarray:
    """Stored curve ``i`` is the render ``lc`` where light arrives, NaN elsewhere.

    Returns the render's visible-and-lit mask (the stored ``visible``).
    """
    mag = lc["mag"].to_numpy()
    lit = lc["visible"].to_numpy() & np.isfinite(mag)  # zero flux: mag = +inf in a render
    stored = ds["mag"][i].astype(np.float64)
    np.testing.assert_array_equal(ds["visible"][i], lit)
    assert np.isnan(stored[~lit]).all() and np.isnan(ds["flux_w_m2"][i][~lit]).all()
    np.testing.assert_allclose(stored[lit], mag[lit], atol=1e-4, rtol=0)
    return lit


def test_labels_reproduce_the_stored_curves(reference):
    labels = reference.labels
    picks = [int(labels.index[labels["class"] == c][0]) for c in ("cylinder", "boxwing", "cubesat")]
    picks.append(int(labels["subsamples"].idxmax()))  # the most motion blur
    # A synthetic curve is always observed: fewer visible samples means zero flux somewhere.
    dark = labels.index[labels["visible_samples"] < 96]
    assert len(dark) > 0, "the reference has no zero-flux sample to check"
    picks.append(int(dark[0]))
    for i in picks:
        row = labels.loc[i]
        geo = _synthetic_from_labels(reference, i)
        # Any size of a shape shares its shadow table (the scale is an area
        # factor), so a curve re-renders exactly, shadowed or not.
        lc = jaxlc.render(jaxlc.scene_from_dict(_scene_from_labels(reference, i)), geo)
        assert _plan_subsamples(lc) == row["subsamples"]
        # the instants the render's refinement chose (its plan line, 2 decimals); a level
        # decision at a threshold may differ between the batched and the single kernel
        assert row["instants_per_exposure"] == pytest.approx(_plan_instants(lc), rel=0.05, abs=0.01)
        lit = _same_as_render(reference, i, lc)
        phase = lc["phase_angle_deg"].to_numpy()
        np.testing.assert_allclose(reference["phase_angle_deg"][i], phase, atol=1e-4)
        np.testing.assert_allclose(reference["range_m"][i], lc["range_m"], rtol=1e-6)
        assert row["phase_mean_deg"] == pytest.approx(phase[lit].mean(), abs=1e-9)
        assert row["visible_samples"] == int(lit.sum())


def _plan_instants(lc) -> float:
    """Instants per exposure that a rendered light curve used: the adaptive refinement's
    mean from its plan text, else the plan's fixed count."""
    m = re.search(r"([\d.]+) instants per exposure", lc.attrs["plan"])
    return float(m.group(1)) if m else float(_plan_subsamples(lc))


def _plan_subsamples(lc) -> int:
    """The per-curve rule's sub-exposures from the plan text of a rendered light curve
    (adaptive blur names it as the count the fixed rule would take)."""
    text = lc.attrs["plan"].split(" | ")[3]  # mesh | convex | shadows | blur | rows
    m = re.match(r"(\d+) per exposure", text) or re.search(r"would take (\d+)", text)
    return int(m.group(1))


def test_real_passes_reproduce_from_tle_and_site(tmp_path):
    from jaxlc.geometry.observe import geometry_table
    from jaxlc.geometry.sites import get_site
    from jaxlc.geometry.tle import read_tles

    data = _config_dict()
    data["dataset"].update(count=4, shard_size=2, samples=60)
    data["class"] = data["class"][:1]
    tle = REPO / "data" / "tle" / "celestrak_cubesat_2025-11.txt"
    data["geometry"] = {
        "source": "passes",
        "tle": str(tle),
        "norad": [27844, 27848, 32785, 35932, 35933, 39090],
        "sites": ["mt-stromlo"],
        "start_utc": "2025-11-07T00:00:00Z",
        "days": 0.5,
        "max_passes": 4,
    }
    data["noise"] = {"zero_point_mag": 20.0, "aperture_m": 0.5}
    cfg = config_from_dict(data, source="passes.toml")
    ds = dataset.generate(cfg, tmp_path / "passes.zarr", workers=0, progress=False)
    assert set(ds.labels["geometry"]) == {"pass"}
    assert (ds.labels["pass_id"] >= 0).all() and (ds.labels["site"] == "mt-stromlo").all()
    tles = {t.norad_id: t for t in read_tles(tle)}
    for i in (0, 3):
        row = ds.labels.loc[i]
        # Independent geometry: the catalogue object from the site, from the label's start.
        geo = geometry_table(
            tles[int(row["norad_id"])],
            get_site(row["site"]),
            jaxlc.io.utc.parse_utc([row["utc_start"]])[0],
            60.0,
            1.0,
            1.0,
        )
        lc = jaxlc.render(jaxlc.scene_from_dict(_scene_from_labels(ds, i)), geo)
        lit = _same_as_render(ds, i, lc)
        assert np.isfinite(ds["mag_noisy"][i][lit]).mean() > 0.9


# ---------------------------------------------------------------------------
# Noise


def test_noise_free_values_kept_beside_noisy_ones(config_path, reference, tmp_path):
    data = _config_dict()
    del data["noise"]
    quiet = dataset.generate(
        config_from_dict(data, source="quiet.toml"),
        tmp_path / "quiet.zarr",
        workers=0,
        count=8,
        progress=False,
    )
    assert "mag_noisy" not in quiet.arrays
    # The noise-free arrays do not depend on the noise model.
    for name in ARRAYS:
        assert np.array_equal(quiet[name][...], reference[name][:8], equal_nan=True), name

    flux = reference["flux_w_m2"][...].astype(np.float64)
    mag = reference["mag"][...].astype(np.float64)
    noisy = reference["mag_noisy"][...].astype(np.float64)
    err = reference["mag_err"][...].astype(np.float64)
    vis = reference["visible"][...]
    np.testing.assert_allclose(mag[vis], photometry.magnitude(flux[vis]), atol=2e-5)
    assert np.isnan(noisy[~vis]).all() and np.isnan(err[~vis]).all()

    # mag_err from its formula: photons, sky, read noise, scintillation (Young 1967).
    t = 1.0
    signal = t * 10 ** (-0.4 * (mag - 18.0))
    scint = 0.09 * 30.0 ** (-2 / 3) * 1.5**1.75 * math.exp(-800.0 / 8000.0) / math.sqrt(2 * t)
    sigma = 2.5 / math.log(10) * np.sqrt(signal + 300.0 * t + 10.0**2 + (scint * signal) ** 2)
    assert (signal[vis] > 0).all()  # a sample with nothing lit and seen is not visible
    np.testing.assert_allclose(err[vis], np.minimum(sigma[vis] / signal[vis], 100.0), rtol=1e-3)

    # The noisy magnitudes scatter by mag_err where the errors are small (Gaussian regime).
    good = vis & np.isfinite(noisy) & (err < 0.05)
    z = (noisy[good] - mag[good]) / err[good]
    assert good.sum() > 500
    assert abs(np.mean(z)) < 0.15 and 0.85 < np.std(z) < 1.15


# ---------------------------------------------------------------------------
# Reading back and the command line


def test_batches_cover_every_curve_once(reference):
    seen = []
    for batch in reference.batches(5, fields=("mag", "visible"), labels=("class_id",), seed=3):
        assert batch["mag"].shape == (len(batch["curve"]), 96)
        np.testing.assert_array_equal(batch["mag"], reference["mag"].oindex[batch["curve"], :])
        np.testing.assert_array_equal(
            batch["class_id"], reference.labels["class_id"].loc[batch["curve"]]
        )
        seen += list(batch["curve"])
    assert sorted(seen) == list(range(18)) and seen != sorted(seen)


def test_batches_cover_every_block_once():
    from jaxlc.dataset.bulk import TAIL_BATCH, batches

    for full, shapes in ((16, {16, 8, TAIL_BATCH}), (64, {64, 32, 16, 8, TAIL_BATCH})):
        for n in range(0, 4 * full):
            calls = batches(n, full)
            covered = [b for start, size in calls for b in range(start, min(start + size, n))]
            assert covered == list(range(n))
            assert {size for _, size in calls} <= shapes  # a few compiled shapes
            assert sum(size for _, size in calls) - n < TAIL_BATCH  # padding: < one tail batch
            # the remainder in at most one call per halving, and one padded
            assert len(calls) <= n // full + len(shapes)


def test_a_curve_does_not_depend_on_its_batch_neighbours(config_path):
    """A class's curves rendered together (in several batches and a padded tail batch,
    adaptive probes and all) give each curve exactly what it gets rendered alone, and
    an adaptive curve does not depend on its plan's instants (a shard leaves them out)."""
    from jaxlc.dataset.bulk import render_class
    from jaxlc.dataset.draw import curve_geometry, curve_scene

    config = load_config(config_path)
    curves = [c for c in (dataset.draw_curve(config, i) for i in range(config.count))]
    adaptive = 0
    for class_id in range(len(config.classes)):
        mine = [c for c in curves if c.class_id == class_id][:6]

        def prepared(cs, plan_instants=True):
            return [
                jaxlc.prepare(
                    jaxlc.scene_from_dict(curve_scene(config, c)),
                    curve_geometry(config, c).arrays,
                    plan_instants=plan_instants,
                )
                for c in cs
            ]

        shard_like = prepared(mine, False)
        adaptive += sum(p.adaptive for p in shard_like)
        together = render_class(config, config.classes[class_id], shard_like)
        for r, c in enumerate(mine):
            alone = render_class(config, config.classes[class_id], prepared([c]))[0]
            np.testing.assert_array_equal(together[r], alone)
    assert adaptive > 0, "no curve of the test config asks for adaptive sub-exposures"


def test_features_are_finite_where_visible(reference):
    """The documented mask: every feature finite where ``visible``, NaN elsewhere, no ±inf."""
    vis = reference["visible"][...]
    assert 0 < vis.mean() < 1
    for name in (*ARRAYS, *NOISY):
        x = reference[name][...]
        assert not np.isinf(x).any(), name
        if name == "visible":
            continue
        if name == "mag_noisy":
            ok = vis & (reference["flux_noisy_w_m2"][...] > 0)
            assert ok.mean() > 0.5 * vis.mean()
        else:
            ok = vis
        assert np.isfinite(x[ok]).all(), name
        if name not in ("phase_angle_deg", "range_m"):
            assert np.isnan(x[~ok]).all(), name
    assert (reference["flux_w_m2"][...][vis] > 0).all()
    assert (reference["mag_err"][...][vis] <= 100).all()
    # The samples the visibility rules pass but no light reaches are the ones left out.
    dark = int(reference.labels.index[reference.labels["visible_samples"] < 96][0])
    observed = reference.geometry(dark)["visible"].to_numpy()
    assert (observed & ~reference["visible"][dark]).any()


def test_readme_training_example_runs(reference):
    """The README's training loop runs without a warning and feeds only finite features."""
    import warnings

    text = (REPO / "README.md").read_text()
    section = text.split("## Bulk datasets", 1)[1]
    code = re.findall(r"```python\n(.*?)```", section, flags=re.S)[0]
    code = code.replace("build/bulk_example.zarr", str(reference.path))
    step = "\n        y = batch"
    assert code.count(step) == 1, "the recipe changed: update this test's probe"
    checked = code.replace(
        step, "\n        seen.append(np.isfinite(x).all() and x.shape[0] > 0)" + step
    )
    seen = []
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        exec(compile(checked, "README.md", "exec"), {"seen": seen, "print": lambda *a: None})
    assert len(seen) == 2 * math.ceil(18 / 32) and all(seen)


def test_cli_generate(config_path, reference, tmp_path, capsys):
    from jaxlc.cli import main

    out = tmp_path / "cli.zarr"
    assert (
        main(["generate", str(config_path), "-o", str(out), "--workers", "0", "--count", "8"]) == 0
    )
    ds = dataset.open(out)
    assert len(ds) == 8
    assert np.array_equal(ds["mag"][...], reference["mag"][:8], equal_nan=True)
    capsys.readouterr()
    bad = tmp_path / "bad.toml"
    bad.write_text(CONFIG.replace("period_s = [5.0, 30.0]", "period_s = [30.0, 5.0]"))
    assert main(["generate", str(bad), "-o", str(tmp_path / "x.zarr")]) == 1
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "period_s" in err[0] and "[30.0, 5.0]" in err[0]
    assert not (tmp_path / "x.zarr").exists()


def test_environment_without_dask_is_explained(monkeypatch, config_path, tmp_path):
    monkeypatch.setitem(sys.modules, "distributed", None)
    with pytest.raises(DatasetError, match=r"jaxlc\[dask\].*--workers 0"):
        dataset.generate(config_path, tmp_path / "x.zarr", workers=2, progress=False)
    assert os.path.exists(tmp_path) and not (tmp_path / "x.zarr").exists()


# ---------------------------------------------------------------------------
# Hostile input: one `error:` line naming the key, the value and the fix; nothing left behind

SMALL = """
[dataset]
count = 4
samples = 16
shard_size = 2
seed = 1

[[class]]
name = "cylinder"
scene = "s3_cylinder"
period_s = [10.0, 100.0]

[geometry]
source = "synthetic"
phase_start_deg = [10.0, 90.0]
phase_end_deg = [30.0, 150.0]
range_start_m = [5.0e5, 3.0e6]
"""


def _edit(old, new):
    assert old in SMALL, old
    return SMALL.replace(old, new)


_GLOSSY = """period_s = 20.0
[[class.material]]
brdf = "as-glossy"
rd = [0.3, 0.8]
rs = [0.1, 0.5]
nu = 100.0"""

#: (id, config text or bytes, needles in the message)
BAD_CONFIGS = [
    ("not-toml", "this is not toml [", ["cfg.toml", "not valid TOML", "line 1"]),
    ("binary", b"\x00\xff\xfe\x89PNG", ["cfg.toml", "not a UTF-8 text file"]),
    ("count-string", _edit("count = 4", 'count = "4"'), ["count = '4'", "whole number"]),
    ("count-zero", _edit("count = 4", "count = 0"), ["count = 0", "[1, 1,000,000,000]"]),
    ("count-negative", _edit("count = 4", "count = -3"), ["count = -3", "whole number"]),
    ("samples-zero", _edit("samples = 16", "samples = 0"), ["samples = 0", "[1, 1,000,000]"]),
    ("shard-zero", _edit("shard_size = 2", "shard_size = 0"), ["shard_size = 0"]),
    (
        "shard-too-big",
        _edit("samples = 16", "samples = 100000").replace("shard_size = 2", "shard_size = 1000"),
        ["shard_size × samples", "1,000 × 100,000", "lower shard_size to at most 10"],
    ),
    ("cadence-string", _edit("seed = 1", 'seed = 1\ncadence_s = "1"'), ["cadence_s = '1'"]),
    ("exposure-negative", _edit("seed = 1", "seed = 1\nexposure_s = -1"), ["exposure_s = -1"]),
    (
        "period-min-above-max",
        _edit("[10.0, 100.0]", "[100.0, 10.0]"),
        ["period_s = [100.0, 10.0]", "low 100 > high 10", "write [low, high]"],
    ),
    ("period-1e-300", _edit("[10.0, 100.0]", "1e-300"), ["period_s = 1e-300", "[0.001, 1e+09]"]),
    ("period-1e300", _edit("[10.0, 100.0]", "1e300"), ["period_s = 1e+300", "[0.001, 1e+09]"]),
    ("period-inf", _edit("[10.0, 100.0]", "inf"), ["period_s = inf", "number or [low, high]"]),
    ("weight-zero", _edit("period_s", "weight = 0\nperiod_s"), ["weight = 0.0", "outside"]),
    ("unknown-scene", _edit('"s3_cylinder"', '"s9_nope"'), ["scene = 's9_nope'", "not found"]),
    (
        "unknown-class-key",
        _edit("period_s", 'colour = "red"\nperiod_s'),
        ["[[class]] #1 (cylinder)", "unknown key 'colour'", "allowed here"],
    ),
    ("unknown-table", SMALL + "\n[extras]\na = 1\n", ["unknown key 'extras'", "allowed here"]),
    ("unknown-source", _edit('"synthetic"', '"orbit"'), ["source = 'orbit'", "'passes'"]),
    (
        "unknown-brdf",
        _edit(
            "period_s = [10.0, 100.0]",
            'period_s = 20.0\n[[class.material]]\nbrdf = "shiny"\nrd = 0.5',
        ),
        ["brdf = 'shiny'", "lambert"],
    ),
    (
        "glossy-over-one",
        _edit("period_s = [10.0, 100.0]", _GLOSSY),
        ["'cylinder' at the high ends", "rd + rs = 0.8 + 0.5 > 1", "rd + rs ≤ 1"],
    ),
    (
        "range-inside-object",
        _edit("[5.0e5, 3.0e6]", "[1.0, 3.0e6]"),
        ["range_start_m", "closest range 1 m", "raise the ranges' low ends"],
    ),
    ("utc-now", _edit('"synthetic"', '"synthetic"\nstart_utc = "now"'), ["start_utc = 'now'"]),
    (
        "noise-negative-sky",
        SMALL + "\n[noise]\nzero_point_mag = 20.0\nsky_e_per_s = -1\n",
        ["[noise]", "sky_e_per_s = -1.0", "outside"],
    ),
]

#: (id, command-line arguments after CONFIG; "OUT" is tmp_path / "out.zarr", needles)
BAD_OPTIONS = [
    ("output-regular-file", ["-o", "FILE"], ["output", "FILE", "folder ending in .zarr"]),
    ("output-file-named-zarr", ["-o", "FILE.zarr"], ["output", "FILE.zarr", "is a file"]),
    ("output-not-zarr", ["-o", "out.h5"], ["output", "out.h5", ".zarr"]),
    ("output-folder-not-store", ["-o", "junk.zarr"], ["junk.zarr", "not a dataset store"]),
    ("output-other-config", ["-o", "REFERENCE"], ["different config", "write to a new path"]),
    ("workers-negative", ["--workers", "-1"], ["--workers", "-1", "[0, "]),
    ("workers-huge", ["--workers", "100000"], ["--workers", "100000", "per core"]),
    ("count-zero", ["--count", "0"], ["--count", "= 0", "whole number"]),
    ("seed-negative", ["--seed", "-5"], ["--seed", "-5"]),
    ("workers-and-scheduler", ["--workers", "2", "--scheduler", "tcp://h:1"], ["not both"]),
    ("scheduler-empty", ["--scheduler", ""], ["--scheduler", "''", "tcp://host:8786"]),
    ("scheduler-garbage", ["--scheduler", "not an address"], ["'not an address'", "port"]),
    ("scheduler-scheme", ["--scheduler", "foo://x:1"], ["'foo://x:1'", "scheme"]),
    (
        "scheduler-unreachable",
        ["--scheduler", "tcp://127.0.0.1:9"],
        ["'tcp://127.0.0.1:9'", "cannot connect", "leave out --scheduler"],
    ),
]


def _run_cli(argv, capsys):
    from jaxlc.cli import main

    capsys.readouterr()
    status = main(argv)
    err = capsys.readouterr().err
    return status, err


def _assert_one_error_line(status, err, needles):
    lines = err.strip().splitlines()
    assert status == 1, err
    assert len(lines) == 1 and lines[0].startswith("error: "), err
    assert "Traceback" not in err
    for needle in needles:
        assert needle in lines[0], (needle, lines[0])


@pytest.mark.parametrize(
    ("text", "needles"), [c[1:] for c in BAD_CONFIGS], ids=[c[0] for c in BAD_CONFIGS]
)
def test_bad_config_gives_one_line_and_no_output(text, needles, tmp_path, capsys):
    cfg = tmp_path / "cfg.toml"
    (cfg.write_bytes if isinstance(text, bytes) else cfg.write_text)(text)
    out = tmp_path / "out.zarr"
    status, err = _run_cli(["generate", str(cfg), "-o", str(out), "--workers", "0"], capsys)
    _assert_one_error_line(status, err, needles)
    assert sorted(p.name for p in tmp_path.iterdir()) == ["cfg.toml"]


@pytest.mark.parametrize(
    ("args", "needles"), [c[1:] for c in BAD_OPTIONS], ids=[c[0] for c in BAD_OPTIONS]
)
def test_bad_options_give_one_line_and_no_output(
    args, needles, tmp_path, capsys, monkeypatch, request
):
    from jaxlc.dataset import runner

    if any(a.startswith("--scheduler") or a == "--workers" for a in args):
        pytest.importorskip("distributed")
    monkeypatch.setattr(runner, "CONNECT_TIMEOUT_S", 1.0)  # the unreachable scheduler
    cfg = tmp_path / "cfg.toml"
    cfg.write_text(SMALL)
    (tmp_path / "FILE").write_text("not a store")
    (tmp_path / "FILE.zarr").write_text("not a store either")
    (tmp_path / "junk.zarr").mkdir()
    before = sorted(p.name for p in tmp_path.iterdir())
    stamp = None
    names = {"FILE": "FILE", "FILE.zarr": "FILE.zarr", "out.h5": "out.h5", "junk.zarr": "junk.zarr"}
    argv = ["generate", str(cfg)]
    for a in args:
        if a == "REFERENCE":
            ref = request.getfixturevalue("reference").path
            stamp = sorted((p.relative_to(ref), p.stat().st_mtime_ns) for p in ref.rglob("*"))
            argv.append(str(ref))
        else:
            argv.append(str(tmp_path / names[a]) if a in names else a)
    if "-o" not in args:
        argv += ["-o", str(tmp_path / "out.zarr")]
    status, err = _run_cli(argv, capsys)
    _assert_one_error_line(status, err, needles)
    assert sorted(p.name for p in tmp_path.iterdir()) == before
    if stamp is not None:  # the other config's store is untouched
        assert sorted((p.relative_to(ref), p.stat().st_mtime_ns) for p in ref.rglob("*")) == stamp


def test_bad_config_paths(tmp_path, capsys):
    for path, needles in (
        (tmp_path, ["dataset config", "is a folder"]),
        (tmp_path / "nope.toml", ["dataset config", "nope.toml", "does not exist"]),
    ):
        out = tmp_path / "out.zarr"
        status, err = _run_cli(["generate", str(path), "-o", str(out)], capsys)
        _assert_one_error_line(status, err, needles)
        assert list(tmp_path.iterdir()) == []


def test_failed_run_removes_only_a_store_it_made(tmp_path, monkeypatch):
    """A new store that fails before its first shard goes; a store being resumed stays."""
    from jaxlc.dataset import runner

    cfg = tmp_path / "small.toml"
    cfg.write_text(SMALL)
    real_run_shard = runner.run_shard

    def broken(*args):
        raise RuntimeError("worker died")

    monkeypatch.setattr(runner, "run_shard", broken)
    with pytest.raises(RuntimeError, match="worker died"):
        dataset.generate(cfg, tmp_path / "new.zarr", workers=0, progress=False)
    assert sorted(p.name for p in tmp_path.iterdir()) == ["small.toml"]

    # An unfinished store: one shard done, then the resuming run fails at once.
    monkeypatch.setattr(runner, "run_shard", real_run_shard)

    def stop(k):
        raise KeyboardInterrupt

    out = tmp_path / "part.zarr"
    with pytest.raises(KeyboardInterrupt):
        dataset.generate(cfg, out, workers=0, progress=False, on_shard=stop)
    monkeypatch.setattr(runner, "run_shard", broken)
    with pytest.raises(RuntimeError, match="worker died"):
        dataset.generate(cfg, out, workers=0, progress=False)
    assert dataset.open(out, partial=True).done.tolist() == [True, False]
