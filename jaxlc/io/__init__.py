"""Input and output at the edges: tables, strict TOML, UTC, atomic files, the cache.

* :mod:`~jaxlc.io.tables` — the geometry and light-curve tables (CSV/Parquet);
* :mod:`~jaxlc.io.observations` — observed tracks (MMT) as light-curve tables;
* :mod:`~jaxlc.io.toml` — the strict reader of scene files and dataset configs;
* :mod:`~jaxlc.io.utc` — the one UTC parser and format;
* :mod:`~jaxlc.io.files` — atomic writes;
* :mod:`~jaxlc.io.cache` — the one cache root (``$XDG_CACHE_HOME/jaxlc``);
* :mod:`~jaxlc.io.provenance` — version and commit for metadata.
"""
