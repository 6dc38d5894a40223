"""Two-line element sets: strict reading, selection by object, epoch choice.

Reads 2-line and 3-line (named, optionally ``0 NAME``) files with LF or CRLF
line ends and any number of epochs per object. Every line is checked before
SGP4 sees it: length, the mod-10 checksum, the catalogue number on both lines
and the numeric fields; an error names the file, the line and the field::

    TLE line 2 checksum is 7, expected 3 (line 17 of falcon9_rb.tle)

Characters after column 69 are ignored (Vallado's verification file puts
start/stop/step times there).
"""

from __future__ import annotations

import dataclasses
import math
import warnings
from pathlib import Path

import pandas as pd

from jaxlc.errors import JaxlcError


class TLEError(JaxlcError):
    """A malformed TLE file, or no TLE for the requested object or time."""


class TLEWarning(UserWarning):
    """A usable TLE with a caveat: stale epoch, bad checksum accepted on request."""


#: TLE epochs older than this before the window start give a warning (days).
STALE_EPOCH_DAYS = 3.0

# (name, first column, last column) of the numeric fields, 1-based inclusive.
_LINE1_FIELDS = [
    ("epoch year", 19, 20),
    ("epoch day", 21, 32),
    ("first derivative of mean motion", 34, 43),
]
_LINE2_FIELDS = [
    ("inclination", 9, 16),
    ("right ascension of the ascending node", 18, 25),
    ("eccentricity", 27, 33),
    ("argument of perigee", 35, 42),
    ("mean anomaly", 44, 51),
    ("mean motion", 53, 63),
]


@dataclasses.dataclass(frozen=True)
class TLE:
    """One element set.

    Attributes:
        name: object name from the line before (3-line files), else "".
        norad_id: catalogue number (Alpha-5 decoded).
        line1, line2: the two lines, 69 characters each.
        epoch_utc: the element-set epoch.
        source: file the set came from.
        lineno: line number of ``line1`` in that file (1-based).
    """

    name: str
    norad_id: int
    line1: str
    line2: str
    epoch_utc: pd.Timestamp
    source: str = "<memory>"
    lineno: int = 0

    def satrec(self):
        """The ``sgp4.api.Satrec`` of this element set (WGS-72, as SGP4 expects)."""
        from sgp4.api import WGS72, Satrec

        return Satrec.twoline2rv(self.line1, self.line2, WGS72)

    @property
    def label(self) -> str:
        return f"{self.norad_id} {self.name}".strip()


def checksum(line: str) -> int:
    """Mod-10 checksum of the first 68 characters (digits count, '-' counts 1)."""
    total = 0
    for ch in line[:68]:
        if ch.isdigit():
            total += int(ch)
        elif ch == "-":
            total += 1
    return total % 10


def _catalogue_number(text: str) -> int | None:
    text = text.strip()
    if text.isdigit():
        return int(text)
    if len(text) == 5 and text[0].isalpha() and text[1:].isdigit():  # Alpha-5
        from sgp4.alpha5 import from_alpha5

        return from_alpha5(text)
    return None


def _epoch(line1: str) -> pd.Timestamp:
    year = int(line1[18:20])
    year += 1900 if year >= 57 else 2000
    day = float(line1[20:32])
    return pd.Timestamp(year=year, month=1, day=1, tz="UTC") + pd.to_timedelta(day - 1.0, unit="D")


def parse_tles(text: str, source: str = "<text>", checksums: str = "error") -> list[TLE]:
    """Parse TLE text.

    Args:
        text: file contents.
        source: file name used in error messages.
        checksums: ``"error"`` (default) rejects a wrong checksum, ``"warn"``
            accepts it with a :class:`TLEWarning`.

    Raises:
        TLEError: naming the line and the field of the first problem.
    """
    if checksums not in ("error", "warn"):
        raise ValueError(f"checksums = {checksums!r} must be 'error' or 'warn'")
    name = ""
    name_line = None
    pending = None  # (lineno, line1)
    out: list[TLE] = []
    where = Path(source).name
    for lineno, raw in enumerate(text.splitlines(), start=1):
        line = raw.rstrip("\r\n")
        if not line.strip() or line.lstrip().startswith("#"):
            continue
        tag = line[:2]
        if tag == "1 ":
            if pending is not None:
                raise TLEError(
                    f"TLE line 1 at line {pending[0]} of {where} is not followed by its line 2"
                )
            pending = (lineno, _check_line(line, 1, lineno, where, checksums))
        elif tag == "2 ":
            if pending is None:
                raise TLEError(f"TLE line 2 at line {lineno} of {where} has no line 1 before it")
            l1_no, line1 = pending
            line2 = _check_line(line, 2, lineno, where, checksums)
            n1, n2 = _catalogue_number(line1[2:7]), _catalogue_number(line2[2:7])
            if n1 != n2:
                raise TLEError(
                    f"TLE catalogue number {line1[2:7].strip()!r} on line 1 but "
                    f"{line2[2:7].strip()!r} on line 2 (lines {l1_no}–{lineno} of {where})"
                )
            this_name = name if name_line == l1_no - 1 else ""
            out.append(TLE(this_name, n1, line1, line2, _epoch(line1), str(source), l1_no))
            pending = None
        else:
            if pending is not None:
                raise TLEError(
                    f"TLE line 1 at line {pending[0]} of {where} is followed by "
                    f"{line.strip()[:30]!r} instead of its line 2"
                )
            name = line.strip()
            name = name[2:].strip() if name.startswith("0 ") else name
            name_line = lineno
    if pending is not None:
        raise TLEError(f"TLE line 1 at line {pending[0]} of {where} is not followed by its line 2")
    return out


def _check_line(line: str, number: int, lineno: int, where: str, checksums: str) -> str:
    at = f"(line {lineno} of {where})"
    if len(line.rstrip()) < 69:
        raise TLEError(
            f"TLE line {number} is truncated: {len(line.rstrip())} characters, expected 69 {at}"
        )
    line = line[:69]
    expected = checksum(line)
    if not line[68].isdigit() or int(line[68]) != expected:
        message = f"TLE line {number} checksum is {line[68]}, expected {expected} {at}"
        if checksums == "error":
            raise TLEError(message + "; a damaged or hand-edited line")
        warnings.warn(message, TLEWarning, stacklevel=3)
    if _catalogue_number(line[2:7]) is None:
        raise TLEError(f"TLE line {number} catalogue number {line[2:7]!r} is not a number {at}")
    fields = _LINE1_FIELDS if number == 1 else _LINE2_FIELDS
    for field, first, last in fields:
        text = line[first - 1 : last].strip()
        if field == "eccentricity":
            text = "0." + text
        try:
            value = float(text)
        except ValueError:
            raise TLEError(
                f"TLE line {number} field {field!r} (columns {first}–{last}) is "
                f"{line[first - 1 : last]!r}, not a number {at}"
            ) from None
        if not math.isfinite(value):
            raise TLEError(f"TLE line {number} field {field!r} is not finite {at}")
    return line


def read_tles(path: str | Path, checksums: str = "error") -> list[TLE]:
    """Read every element set in a file (see :func:`parse_tles`)."""
    path = Path(path)
    if not path.is_file():
        raise TLEError(f"TLE file {str(path)!r} does not exist")
    try:
        text = path.read_text(encoding="ascii", errors="strict")
    except UnicodeDecodeError as exc:
        raise TLEError(f"{path}: not a plain-text TLE file ({exc.reason})") from None
    tles = parse_tles(text, source=str(path), checksums=checksums)
    if not tles:
        raise TLEError(f"{path}: no TLE found")
    return tles


def select_objects(
    tles: list[TLE], norad_ids: list[int] | None = None, names: list[str] | None = None
) -> list[TLE]:
    """Keep the element sets of the requested objects (all when neither is given).

    Names match case-insensitively, exactly or as a unique substring.
    """
    if not norad_ids and not names:
        return list(tles)
    keep: set[int] = set()
    available = {t.norad_id for t in tles}
    for n in norad_ids or []:
        if n not in available:
            some = ", ".join(str(x) for x in sorted(available)[:10])
            raise TLEError(f"NORAD {n} is not in {Path(tles[0].source).name} (it has {some}…)")
        keep.add(n)
    for name in names or []:
        key = name.strip().lower()
        exact = {t.norad_id for t in tles if t.name.lower() == key}
        partial = {t.norad_id for t in tles if key in t.name.lower()}
        found = exact or partial
        if not found:
            raise TLEError(f"no object named {name!r} in {Path(tles[0].source).name}")
        if len(found) > 1:
            labels = sorted({t.label for t in tles if t.norad_id in found})[:8]
            raise TLEError(
                f"name {name!r} matches several objects: {', '.join(labels)}; give --norad"
            )
        keep |= found
    return [t for t in tles if t.norad_id in keep]


def latest_before(tles: list[TLE], start_utc: pd.Timestamp) -> list[TLE]:
    """One element set per object: the latest epoch at or before ``start_utc``.

    Warns when that epoch is more than :data:`STALE_EPOCH_DAYS` before the
    start, and when the start precedes every epoch of an object (its first
    set is then used).
    """
    by_object: dict[int, list[TLE]] = {}
    for t in tles:
        by_object.setdefault(t.norad_id, []).append(t)
    chosen = []
    for sets in by_object.values():
        sets = sorted(sets, key=lambda t: t.epoch_utc)
        before = [t for t in sets if t.epoch_utc <= start_utc]
        if before:
            pick = before[-1]
            age = (start_utc - pick.epoch_utc).total_seconds() / 86400.0
            if age > STALE_EPOCH_DAYS:
                warnings.warn(
                    f"TLE of {pick.label} has epoch {pick.epoch_utc:%Y-%m-%d %H:%M}, "
                    f"{age:.1f} days before the window start; SGP4 errors grow by km per day",
                    TLEWarning,
                    stacklevel=2,
                )
        else:
            pick = sets[0]
            ahead = (pick.epoch_utc - start_utc).total_seconds() / 86400.0
            warnings.warn(
                f"the window starts {ahead:.1f} days before the first TLE epoch of "
                f"{pick.label} ({pick.epoch_utc:%Y-%m-%d %H:%M}); propagating it backwards",
                TLEWarning,
                stacklevel=2,
            )
        chosen.append(pick)
    return chosen
