"""Benchmark: historian ingest throughput (CSV and Parquet) into a DuckDB store.

Generates a long-format export of ``--rows`` samples over ``--tags`` tags in a
temporary directory, once as CSV (ISO 8601 text with offsets, values as text)
and once as Parquet (native types), and ingests each into a fresh store with
:func:`valvediag.store.ingest.ingest_exports`. Every tag has its own time stamps
(millisecond jitter, as compressed exports have), so the time-stamp parser
cannot reuse parsed values across tags: the worst case. About 0.1 % of the
values are PI digital states.

Each ingest runs in a child process, so the reported peak memory is that of an
ingest, not of the generator. Prints plain lines, e.g.
``ingest csv: 2,345,678 rows/s``. Not a timed test.
"""
from __future__ import annotations

import argparse
import json
import os
import resource
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np
import polars as pl

ROWS = 3_000_000
TAGS = 300
STATES = ["I/O Timeout", "Bad Input", "Shutdown", "No Data"]


def make_export(rows: int, tags: int, seed: int = 0) -> pl.DataFrame:
    """A long export: tag, timestamp (datetime, UTC), value (text with states)."""
    rng = np.random.default_rng(seed)
    n = rows // tags * tags
    k = np.arange(n)
    tag_idx, step = k % tags, k // tags
    t_ms = step * 1000 + rng.integers(0, 1000, size=n)  # per-tag jitter
    value = 50 + 10 * np.sin(step / 50 + tag_idx) + rng.normal(0, 0.1, n)
    bad = rng.random(n) < 0.001
    state = np.where(bad, rng.integers(0, len(STATES), n), -1)
    return pl.DataFrame({"i": tag_idx, "ms": t_ms, "v": value, "s": state}).select(
        tag=pl.format("TAG{}", pl.col("i")),
        timestamp=pl.datetime(2024, 1, 1, time_unit="ms", time_zone="UTC")
        + pl.duration(milliseconds=pl.col("ms")),
        value=pl.when(pl.col("s") >= 0)
        .then(pl.col("s").replace_strict(list(range(len(STATES))), STATES))
        .otherwise(pl.col("v").round(4).cast(pl.String)),
    )


def _child_ingest(path: str, db: str, force: bool) -> None:
    """Run in a child process: ingest ``path`` into ``db`` and print JSON figures."""
    from valvediag.store.database import Store
    from valvediag.store.ingest import ingest_exports

    with Store(db) as store:
        t = time.perf_counter()
        report = ingest_exports(store, [path], force=force)
        elapsed = time.perf_counter() - t
        assert report.ok, report.errors
        samples = store.counts()["samples"]
    peak = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024
    print(json.dumps({"seconds": elapsed, "inserted": report.rows_inserted,
                      "duplicates": report.rows_skipped_duplicate, "samples": samples,
                      "peak_mb": peak}))


def _run_child(path: Path, db: Path, force: bool = False) -> dict:
    cmd = [sys.executable, __file__, "--child", str(path), str(db)] + (["--force"] if force else [])
    out = subprocess.run(cmd, check=True, capture_output=True, text=True).stdout
    return json.loads(out.strip().splitlines()[-1])


def main(argv=None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--rows", type=int, default=ROWS)
    parser.add_argument("--tags", type=int, default=TAGS)
    parser.add_argument("--child", nargs=2, metavar=("EXPORT", "DB"), help=argparse.SUPPRESS)
    parser.add_argument("--force", action="store_true", help=argparse.SUPPRESS)
    args = parser.parse_args(argv)
    if args.child:
        _child_ingest(*args.child, force=args.force)
        return

    with tempfile.TemporaryDirectory(prefix="valvediag-bench-") as tmp:
        tmp = Path(tmp)
        t = time.perf_counter()
        frame = make_export(args.rows, args.tags)
        csv_path, pq_path = tmp / "export.csv", tmp / "export.parquet"
        frame.write_parquet(pq_path)
        frame.with_columns(pl.col("timestamp").dt.strftime("%Y-%m-%dT%H:%M:%S%.3f+00:00")
                           ).write_csv(csv_path)
        n = frame.height
        del frame
        print(f"generated: {n:,} rows, {args.tags} tags in {time.perf_counter() - t:.1f} s "
              f"(csv {csv_path.stat().st_size / 1e6:.0f} MB, "
              f"parquet {pq_path.stat().st_size / 1e6:.0f} MB)")

        peaks = {}
        for label, path in (("csv", csv_path), ("parquet", pq_path)):
            r = _run_child(path, tmp / f"{label}.duckdb")
            assert r["samples"] == r["inserted"] == n
            peaks[label] = r["peak_mb"]
            print(f"ingest {label}: {r['inserted'] / r['seconds']:,.0f} rows/s "
                  f"({r['inserted']:,} rows in {r['seconds']:.1f} s)")
        r = _run_child(pq_path, tmp / "csv.duckdb", force=True)
        assert r["inserted"] == 0 and r["duplicates"] == n
        print(f"re-ingest same samples (all duplicates): {n / r['seconds']:,.0f} rows/s "
              f"({r['inserted']} inserted)")
        print(f"store size: {(tmp / 'csv.duckdb').stat().st_size / 1e6:.0f} MB for {n:,} rows")

    print(f"peak memory, csv ingest: {peaks['csv']:,.0f} MB")
    print(f"peak memory, parquet ingest: {peaks['parquet']:,.0f} MB")
    print(f"peak memory, generator: "
          f"{resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024:,.0f} MB")
    print(f"cpu count: {os.cpu_count()}")


if __name__ == "__main__":
    main()
