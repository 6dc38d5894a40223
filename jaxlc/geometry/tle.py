"""Two-line element sets: strict reading, selection by object, epoch choice.

Reads 2-line and 3-line (named, optionally ``0 NAME``) files with LF or CRLF
line ends and any number of epochs per object. Every line is checked before
SGP4 sees it, because SGP4's own reader silently misreads damaged lines (a
BSTAR of ``1x005-2`` becomes infinite, an epoch day of 999 another date):
length, the mod-10 checksum, the blank columns between fields, the catalogue
number on both lines, every numeric field and its range (epoch day 1 … 365 or
366, inclination 0–180°, angles 0–360°, mean motion > 0). An error names the
file, the line and the field::

    TLE line 2 checksum is 7, expected 3 (line 17 of falcon9_rb.tle)

Characters after column 69 are ignored (Vallado's verification file puts
start/stop/step times there).
"""

from __future__ import annotations

import dataclasses
import re
import warnings
from pathlib import Path

import pandas as pd

from jaxlc.errors import JaxlcError


class TLEError(JaxlcError):
    """A malformed TLE file, or no TLE for the requested object or time."""


class TLEWarning(UserWarning):
    """A usable TLE with a caveat: stale epoch, bad checksum accepted on request."""


#: An element set used more than this many days from its epoch is *stale*
#: (days): SGP4 prediction errors grow by roughly 1–3 km per day away from
#: the epoch, so after two weeks positions are tens of km and pass times tens
#: of seconds off. ``latest_before`` warns and ``jaxlc passes`` marks such passes.
STALE_EPOCH_DAYS = 14.0

#: No element set is older than the first satellite (Sputnik 1, 1957-10-04);
#: the two-digit TLE year cannot express an earlier epoch either.
FIRST_EPOCH_UTC = pd.Timestamp("1957-10-04", tz="UTC")

# (name, first column, last column, (lowest, highest) or None) of the numeric
# fields, 1-based inclusive. The epoch day's range depends on the year (below).
_LINE1_FIELDS = [
    ("epoch year", 19, 20, (0, 99)),
    ("epoch day", 21, 32, None),
    ("first derivative of mean motion", 34, 43, None),
]
_LINE2_FIELDS = [
    ("inclination", 9, 16, (0.0, 180.0)),
    ("right ascension of the ascending node", 18, 25, (0.0, 360.0)),
    ("eccentricity", 27, 33, None),
    ("argument of perigee", 35, 42, (0.0, 360.0)),
    ("mean anomaly", 44, 51, (0.0, 360.0)),
    ("mean motion", 53, 63, None),
]
# Fields with an implied decimal point and exponent, e.g. " 12345-3" = 0.12345e-3.
_LINE1_EXPONENTIAL = [("second derivative of mean motion", 45, 52), ("BSTAR drag term", 54, 61)]
_EXPONENTIAL = re.compile(r"[ +-]\d{5}[ +-]\d")
_BOTH_LINES = "; every element set needs its line 1 and line 2, one after the other"
# Columns that must be blank (1-based): SGP4 splits the fields at these.
_BLANK_COLUMNS = {1: (2, 9, 18, 33, 44, 53, 62, 64), 2: (2, 8, 17, 26, 34, 43, 52)}


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

    def age_days(self, utc: pd.Timestamp) -> float:
        """|utc − epoch| in days: how far SGP4 extrapolates this set to reach ``utc``."""
        return abs((utc - self.epoch_utc).total_seconds()) / 86400.0


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
    year = _epoch_year(line1)
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
                    f"{_BOTH_LINES}"
                )
            pending = (lineno, _check_line(line, 1, lineno, where, checksums))
        elif tag == "2 ":
            if pending is None:
                raise TLEError(
                    f"TLE line 2 at line {lineno} of {where} has no line 1 before it{_BOTH_LINES}"
                )
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
                    f"{line.strip()[:30]!r} instead of its line 2{_BOTH_LINES}"
                )
            name = line.strip()
            name = name[2:].strip() if name.startswith("0 ") else name
            name_line = lineno
    if pending is not None:
        raise TLEError(
            f"TLE line 1 at line {pending[0]} of {where} is not followed by its line 2{_BOTH_LINES}"
        )
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
    fix = "; a damaged or hand-edited line: get the element set again from its source"
    for column in _BLANK_COLUMNS[number]:
        if line[column - 1] != " ":
            raise TLEError(
                f"TLE line {number} column {column} is {line[column - 1]!r}, expected a blank "
                f"between fields (shifted columns?) {at}{fix}"
            )
    if _catalogue_number(line[2:7]) is None:
        raise TLEError(f"TLE line {number} catalogue number {line[2:7]!r} is not a number {at}")
    for field, first, last, bounds in _LINE1_FIELDS if number == 1 else _LINE2_FIELDS:
        raw = line[first - 1 : last]
        value = _field_value(field, raw)
        if value is None:
            raise TLEError(
                f"TLE line {number} field {field!r} (columns {first}–{last}) is {raw!r}, "
                f"not a number {at}{fix}"
            )
        if bounds is not None and not bounds[0] <= value <= bounds[1]:
            raise TLEError(
                f"TLE line {number} field {field!r} (columns {first}–{last}) is {raw.strip()}, "
                f"outside {bounds[0]:g} … {bounds[1]:g} {at}{fix}"
            )
        if field == "mean motion" and value <= 0:
            raise TLEError(
                f"TLE line {number} field 'mean motion' (columns {first}–{last}) is "
                f"{raw.strip()} rev/day; it must be > 0 {at}{fix}"
            )
    if number == 1:
        for field, first, last in _LINE1_EXPONENTIAL:
            raw = line[first - 1 : last]
            if not _EXPONENTIAL.fullmatch(raw):
                raise TLEError(
                    f"TLE line 1 field {field!r} (columns {first}–{last}) is {raw!r}, not of "
                    f"the form ' 12345-3' (sign, 5 digits, exponent sign and digit) {at}{fix}"
                )
        year, day = _epoch_year(line), float(line[20:32])
        last_day = 366.99999999 if _is_leap(year) else 365.99999999
        if not 1.0 <= day <= last_day:
            kind = "a leap year" if _is_leap(year) else "not a leap year"
            raise TLEError(
                f"TLE line 1 epoch day {line[20:32].strip()} (columns 21–32) is outside "
                f"1 … {last_day:.8f} for {year} ({kind}) {at}{fix}"
            )
    return line


def _field_value(field: str, raw: str) -> float | None:
    """The value of a numeric field (its columns), or None if it is not one as TLEs write it."""
    if field == "eccentricity":  # implied leading "0."; SGP4 reads blanks as zeros
        digits = raw.replace(" ", "0")
        return float("0." + digits) if digits.isdigit() else None
    text = raw.strip()
    if field == "epoch year":
        return float(text) if text.isdigit() else None
    if not re.fullmatch(r"[+-]?(\d+\.\d*|\.\d+)", text):
        return None  # the point is part of the format; refuses "nan", "inf" and "1e5" too
    return float(text)


def _epoch_year(line1: str) -> int:
    """Four-digit epoch year (57–99 → 1957–1999, 00–56 → 2000–2056)."""
    year = int(line1[18:20])
    return year + (1900 if year >= 57 else 2000)


def _is_leap(year: int) -> bool:
    return year % 4 == 0 and (year % 100 != 0 or year % 400 == 0)


def read_tles(path: str | Path, checksums: str = "error") -> list[TLE]:
    """Read every element set in a file (see :func:`parse_tles`).

    Raises:
        TLEError: a missing file or a folder, a binary (non-ASCII or control
        characters) or empty file, or any problem :func:`parse_tles` finds.
    """
    path = Path(path)
    if path.is_dir():
        raise TLEError(f"TLE file {str(path)!r} is a folder; give the TLE file inside it")
    if not path.exists():
        raise TLEError(f"TLE file {str(path)!r} does not exist")
    if not path.is_file():
        raise TLEError(f"TLE file {str(path)!r} is not a regular file; give a text file")
    data = path.read_bytes()
    bad = re.search(rb"[^\t\n\r\x20-\x7e]", data)
    if bad is not None:
        lineno = data.count(b"\n", 0, bad.start()) + 1
        raise TLEError(
            f"{path}: not a plain-text TLE file (byte {bad.group()!r} at line {lineno}); "
            "give a text file of 2- or 3-line element sets (ASCII)"
        )
    tles = parse_tles(data.decode("ascii"), source=str(path), checksums=checksums)
    if not tles:
        what = "is empty" if not data.strip() else "holds no TLE"
        raise TLEError(
            f"{path} {what}: expected pairs of 69-character lines starting with '1 ' and '2 ' "
            "(optionally after a name line)"
        )
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
            more = f" and {len(available) - 10} more" if len(available) > 10 else ""
            raise TLEError(
                f"NORAD {n} is not in {Path(tles[0].source).name}, which has {some}{more}; "
                "give one of those to --norad, or another TLE file"
            )
        keep.add(n)
    for name in names or []:
        key = name.strip().lower()
        exact = {t.norad_id for t in tles if t.name.lower() == key}
        partial = {t.norad_id for t in tles if key in t.name.lower()}
        found = exact or partial
        if not found:
            some = ", ".join(sorted({t.label for t in tles})[:6])
            raise TLEError(
                f"no object named {name!r} in {Path(tles[0].source).name} (it has {some}…); "
                "give a name or part of one from the file, or --norad"
            )
        if len(found) > 1:
            labels = sorted({t.label for t in tles if t.norad_id in found})[:8]
            raise TLEError(
                f"name {name!r} matches several objects: {', '.join(labels)}; give --norad"
            )
        keep |= found
    return [t for t in tles if t.norad_id in keep]


def latest_before(tles: list[TLE], start_utc: pd.Timestamp) -> list[TLE]:
    """One element set per object: the latest epoch at or before ``start_utc``.

    Warns (:class:`TLEWarning`) when the chosen epoch is more than
    :data:`STALE_EPOCH_DAYS` from the start: before it, or after it when the
    start precedes every epoch of an object (its first set is then used and
    propagated backwards).

    Raises:
        TLEError: a start before :data:`FIRST_EPOCH_UTC`.
    """
    if start_utc < FIRST_EPOCH_UTC:
        raise TLEError(
            f"window start {start_utc:%Y-%m-%d %H:%M} UTC is before {FIRST_EPOCH_UTC:%Y-%m-%d}, "
            "the launch of the first satellite: no element set describes an orbit then; "
            "give a --start near the TLE epochs"
        )
    by_object: dict[int, list[TLE]] = {}
    for t in tles:
        by_object.setdefault(t.norad_id, []).append(t)
    chosen = []
    for sets in by_object.values():
        sets = sorted(sets, key=lambda t: t.epoch_utc)
        before = [t for t in sets if t.epoch_utc <= start_utc]
        pick = before[-1] if before else sets[0]
        age = pick.age_days(start_utc)
        if before and age > STALE_EPOCH_DAYS:
            warnings.warn(
                f"TLE of {pick.label} has epoch {pick.epoch_utc:%Y-%m-%d %H:%M}, "
                f"{age:.1f} days before the window start; SGP4 errors grow by km per day",
                TLEWarning,
                stacklevel=2,
            )
        elif not before and age > STALE_EPOCH_DAYS:
            warnings.warn(
                f"the window starts {age:.1f} days before the first TLE epoch of "
                f"{pick.label} ({pick.epoch_utc:%Y-%m-%d %H:%M}); propagating it backwards",
                TLEWarning,
                stacklevel=2,
            )
        chosen.append(pick)
    return chosen
