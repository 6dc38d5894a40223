"""UTC times at the edges: one parser and one format for every file and option.

Inside jaxlc times are float64 seconds from an explicit origin; UTC appears
only in files (tables, scene epochs, configs, observation tracks) and on the
command line, always as ISO 8601 (any offset; none means UTC).
"""

from __future__ import annotations

import functools
import re

import pandas as pd

from jaxlc.errors import JaxlcError

EXAMPLE = "2019-07-07T12:00:00Z"


def parse_utc(values, where: str = "utc", error: type[Exception] = JaxlcError) -> pd.DatetimeIndex:
    """Parse ISO 8601 times (a sequence) to a tz-aware UTC index.

    Strict: every value must be a date and time written out (pandas' words
    ``now``/``today`` would make results depend on the wall clock, and empty
    or ``NaT`` values would become missing times).

    Raises:
        ``error``: naming ``where`` and the first value that is not a time.
    """
    series = pd.Series(values, dtype=object)
    written = series.astype(str).str.match(_DATE)
    try:
        times = pd.DatetimeIndex(pd.to_datetime(series, utc=True, format="ISO8601"))
        bad = ~written.to_numpy() | times.isna()
    except (ValueError, TypeError, OverflowError):
        times, bad = None, None
    for i, v in enumerate(series):
        if bad is not None and not bad[i]:
            continue
        try:
            ok = written.iloc[i] and not pd.isna(
                pd.to_datetime(pd.Series([v], dtype=object), utc=True, format="ISO8601")[0]
            )
        except (ValueError, TypeError, OverflowError):
            ok = False
        if not ok:
            row = "" if len(series) == 1 else f" (row {i})"
            raise error(f"{where} = {v!r}{row} is not an ISO 8601 UTC time like {EXAMPLE}")
    if times is None:
        raise error(f"{where}: cannot read the times as ISO 8601 UTC (e.g. {EXAMPLE})")
    return times


#: A written-out date: four-digit year, month and day (then anything pandas' ISO 8601 parser takes).
_DATE = re.compile(r"\s*\d{4}-?\d{2}-?\d{2}")


def utc_timestamp(value, where: str = "utc", error: type[Exception] = JaxlcError) -> pd.Timestamp:
    """One ISO 8601 time (str or Timestamp) as a tz-aware UTC ``pandas.Timestamp``."""
    if isinstance(value, pd.Timestamp):
        return value.tz_localize("UTC") if value.tzinfo is None else value.tz_convert("UTC")
    if not isinstance(value, str) or not value.strip():
        raise error(f"{where} = {value!r} is not an ISO 8601 UTC time like {EXAMPLE}")
    return _parsed_once(value, where, error)


@functools.lru_cache(maxsize=1024)
def _parsed_once(value: str, where: str, error: type[Exception]) -> pd.Timestamp:
    """:func:`parse_utc` of one text, remembered (Timestamps are immutable; errors are
    not cached): a dataset parses the same start once per curve, ~1 ms each."""
    return parse_utc([value], where, error)[0]


def format_utc(times) -> list[str]:
    """ISO 8601 strings with microseconds and a Z suffix."""
    return [format_utc_time(t) for t in pd.DatetimeIndex(times)]


def format_utc_time(time: pd.Timestamp) -> str:
    """One UTC :class:`pandas.Timestamp` as :func:`format_utc` writes it (without making
    an index: a dataset writes one per curve)."""
    return time.strftime("%Y-%m-%dT%H:%M:%S.%fZ")
