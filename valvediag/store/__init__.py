"""
The DuckDB store: samples, the registry, runs, verdicts and history.

* :mod:`~valvediag.store.database`: :class:`Store`, the only place that runs
  SQL (the queries live in ``sql/``).
* :mod:`~valvediag.store.ingest`: historian exports into the store, each file
  once, no sample twice.
* :mod:`~valvediag.store.partitions`: loops' windows read in one query, or
  written to Parquet for workers that cannot open the store.
* :mod:`~valvediag.store.lock`: one scan per store at a time.
"""
from .database import Store, StoreLockedError
from .ingest import FileIngest, IngestReport, ingest_exports
from .lock import ScanLock, ScanLockedError

__all__ = ["Store", "StoreLockedError", "ingest_exports", "IngestReport", "FileIngest",
           "ScanLock", "ScanLockedError"]
