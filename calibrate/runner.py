"""Run the Blender worker in its own environment, with a time-out and clear errors."""

from __future__ import annotations

import subprocess
import threading
import time
from collections import deque
from pathlib import Path

import numpy as np

from calibrate.environment import find_blender_environment
from jaxlc import JaxlcError

WORKER = Path(__file__).resolve().parent / "worker.py"


class BlenderError(JaxlcError):
    """The Blender worker is missing, failed, or did not finish in time."""


def run_worker(job_dir: Path, timeout_s: float, progress=None) -> dict:
    """Render a job; returns ``{"pixel_sum": (T,), "seconds": (T,)}``.

    Args:
        job_dir: folder written by :func:`calibrate.job.write_job`.
        timeout_s: kill the worker after this many seconds.
        progress: optional callable(done_frames, total_frames).

    Raises:
        BlenderError: ``.venv-blender`` is missing (run ``make setup``), the worker
            exited non-zero (its stderr is quoted), or it ran past ``timeout_s``.
    """
    env = find_blender_environment()
    if not env.available:
        raise BlenderError(f"the Blender environment is {env.describe()}")
    proc = subprocess.Popen(
        [str(env.python), str(WORKER), str(job_dir)],
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
    )
    err_tail: deque[str] = deque(maxlen=30)
    reader = threading.Thread(target=lambda: err_tail.extend(proc.stderr), daemon=True)
    reader.start()
    deadline = time.monotonic() + timeout_s
    timer = threading.Timer(timeout_s, proc.kill)
    timer.start()
    try:
        for line in proc.stdout:
            if line.startswith("FRAME ") and progress is not None:
                _, done, total, _ = line.split()
                progress(int(done), int(total))
        proc.wait()
    finally:
        timer.cancel()
    reader.join(timeout=5)
    if time.monotonic() >= deadline and proc.returncode != 0:
        raise BlenderError(
            f"the Blender worker did not finish within {timeout_s:.0f} s and was stopped "
            f"(job {job_dir}); raise the time-out or render fewer or smaller frames"
        )
    if proc.returncode != 0:
        detail = " | ".join(line.strip() for line in err_tail if line.strip())[-1500:]
        raise BlenderError(
            f"the Blender worker failed (exit status {proc.returncode}, job {job_dir}): {detail}"
        )
    result = Path(job_dir) / "result.npz"
    if not result.is_file():
        raise BlenderError(f"the Blender worker wrote no result (job {job_dir})")
    with np.load(result) as z:
        return {k: z[k] for k in z.files}


def default_timeout_s(frames: int, resolution: int, samples: int, keyframes: int = 1) -> float:
    """A generous limit: ~20 µs per pixel-sample-keyframe plus a minute to start."""
    return 60.0 + frames * (1.0 + 2e-5 * resolution**2 * samples * max(1, keyframes) / 64)
