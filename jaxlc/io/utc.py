"""UTC times at the edges: one parser and one format for every file and option.

Inside jaxlc times are float64 seconds from an explicit origin; UTC appears
only in files (tables, scene epochs, configs, observation tracks) and on the
command line, always as ISO 8601 (any offset; none means UTC).
"""

from __future__ import annotations

import pandas as pd

from jaxlc.errors import JaxlcError

EXAMPLE = "2019-07-07T12:00:00Z"


def parse_utc(values, where: str = "utc", error: type[Exception] = JaxlcError) -> pd.DatetimeIndex:
    """Parse ISO 8601 times (a sequence) to a tz-aware UTC index.

    Raises:
        ``error``: naming ``where`` and the first value that is not a time.
    """
    series = pd.Series(values, dtype=object)
    try:
        return pd.DatetimeIndex(pd.to_datetime(series, utc=True, format="ISO8601"))
    except (ValueError, TypeError, OverflowError):
        pass
    for i, v in enumerate(series):
        try:
            pd.to_datetime(pd.Series([v], dtype=object), utc=True, format="ISO8601")
        except (ValueError, TypeError, OverflowError):
            row = "" if len(series) == 1 else f" (row {i})"
            raise error(
                f"{where} = {v!r}{row} is not an ISO 8601 UTC time like {EXAMPLE}"
            ) from None
    raise error(f"{where}: cannot read the times as ISO 8601 UTC (e.g. {EXAMPLE})")


def utc_timestamp(value, where: str = "utc", error: type[Exception] = JaxlcError) -> pd.Timestamp:
    """One ISO 8601 time (str or Timestamp) as a tz-aware UTC ``pandas.Timestamp``."""
    if isinstance(value, pd.Timestamp):
        return value.tz_localize("UTC") if value.tzinfo is None else value.tz_convert("UTC")
    if not isinstance(value, str) or not value.strip():
        raise error(f"{where} = {value!r} is not an ISO 8601 UTC time like {EXAMPLE}")
    return parse_utc([value], where, error)[0]


def format_utc(times) -> list[str]:
    """ISO 8601 strings with microseconds and a Z suffix."""
    return [t.strftime("%Y-%m-%dT%H:%M:%S.%fZ") for t in pd.DatetimeIndex(times)]
