"""
Readers: what comes in from outside, parsed and checked, never stored here.

* :mod:`~valvediag.io.exports`: historian exports (CSV, Parquet; long or
  wide) to samples plus quarantined rows.
* :mod:`~valvediag.io.registry`: the loop registry ``loops.csv``.
* :mod:`~valvediag.io.loopfile`: the single-loop CSV of the one-loop commands.
"""
from .exports import ExportError, ParsedExport, expand_paths, read_export
from .loopfile import LoopFileError, LoopRecord, read_loop_csv
from .registry import LoopSpec, RegistryError, read_loops_csv

__all__ = ["ExportError", "ParsedExport", "expand_paths", "read_export", "LoopFileError",
           "LoopRecord", "read_loop_csv", "LoopSpec", "RegistryError", "read_loops_csv"]
