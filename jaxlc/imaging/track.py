"""Frame-to-frame linking of objects (point sources that are not catalogue stars).

Each track predicts its next position from its last two detections (constant
velocity in pixels, extrapolated at most :data:`MAX_EXTRAPOLATION_S`), and the
frame's detections are assigned to the tracks by the Hungarian method on the
distance to the predictions, within a gate; a detection left over starts a
new track. Several objects per frame are several tracks.
"""

from __future__ import annotations

import dataclasses

import numpy as np
from scipy.optimize import linear_sum_assignment

#: The longest a velocity is extrapolated over a gap (s); beyond, the last position.
MAX_EXTRAPOLATION_S = 30.0


@dataclasses.dataclass
class Track:
    """One object's detections: frame indices, times (s) and (x, y) positions (pixels)."""

    track_id: int
    frames: list[int] = dataclasses.field(default_factory=list)
    times_s: list[float] = dataclasses.field(default_factory=list)
    xy: list[tuple[float, float]] = dataclasses.field(default_factory=list)

    def predict(self, t_s: float) -> np.ndarray:
        """Predicted (x, y) at ``t_s``."""
        last = np.asarray(self.xy[-1])
        if len(self.xy) < 2 or t_s - self.times_s[-1] > MAX_EXTRAPOLATION_S:
            return last
        dt = self.times_s[-1] - self.times_s[-2]
        if dt <= 0:
            return last
        velocity = (last - np.asarray(self.xy[-2])) / dt
        return last + velocity * (t_s - self.times_s[-1])

    def add(self, frame: int, t_s: float, xy) -> None:
        self.frames.append(frame)
        self.times_s.append(float(t_s))
        self.xy.append((float(xy[0]), float(xy[1])))


def assign(tracks: list[Track], t_s: float, xy: np.ndarray, gate_px: float) -> np.ndarray:
    """Match detections to tracks (Hungarian, within ``gate_px`` of the predictions).

    Args:
        tracks: the live tracks.
        t_s: this frame's time (s).
        xy: (N, 2) detections.
        gate_px: the largest accepted distance (pixels).

    Returns:
        (N,) index of the matched track per detection, −1 where none.
    """
    out = np.full(len(xy), -1, dtype=int)
    if len(xy) == 0 or not tracks:
        return out
    pred = np.stack([tr.predict(t_s) for tr in tracks])
    dist = np.linalg.norm(xy[:, None, :] - pred[None, :, :], axis=-1)
    cost = np.where(dist <= gate_px, dist, 1e9)
    rows, cols = linear_sum_assignment(cost)
    for r, c in zip(rows, cols, strict=True):
        if dist[r, c] <= gate_px:
            out[r] = c
    return out


class Tracker:
    """Online tracker: feed frames in time order with :meth:`update`."""

    def __init__(self, gate_px: float = 10.0):
        self.gate_px = float(gate_px)
        self.tracks: list[Track] = []

    def update(self, frame: int, t_s: float, xy) -> np.ndarray:
        """Link this frame's detections; returns each detection's track id."""
        xy = np.asarray(xy, dtype=float).reshape(-1, 2)
        match = assign(self.tracks, t_s, xy, self.gate_px)
        ids = np.empty(len(xy), dtype=int)
        for i, m in enumerate(match):
            if m < 0:
                self.tracks.append(Track(len(self.tracks)))
                m = len(self.tracks) - 1
            self.tracks[m].add(frame, t_s, xy[i])
            ids[i] = self.tracks[m].track_id
        return ids

    def predictions(self, t_s: float) -> dict[int, np.ndarray]:
        """Every track's predicted position at ``t_s``."""
        return {tr.track_id: tr.predict(t_s) for tr in self.tracks}
