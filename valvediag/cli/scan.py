"""``valvediag scan``: the nightly plant scan, run here and now.

The command checks its inputs, then runs the Prefect flow ``nightly-scan``
(:mod:`valvediag.pipelines.nightly`, the flow the ``nightly-scan/nightly`` deployment
runs) in this process, with a progress display. Prefect is imported only
inside the handler.
"""
from __future__ import annotations

import argparse
import contextlib
import datetime as dt
import json
import os
import sys
import zoneinfo
from pathlib import Path

from ..plain import one_line
from . import CommandError

#: Exit code of a scan that ran but left some export out of the store (run ``partial``).
EXIT_PARTIAL = 3

HELP = """\
Scan every control loop of a plant: ingest the historian exports into the
DuckDB store, classify each loop of loops.csv over its latest WINDOW hours
(stiction, backlash, linear oscillation, no oscillation, ...) and write
OUT/report.html (ranked maintenance report), OUT/work_orders.csv (one row per
loop needing action) and OUT/verdicts.json (every loop). The store keeps the
samples and the history of runs; exports ingested before are skipped.

This runs the same Prefect flow as the nightly deployment (nightly-scan/nightly,
see 'make serve'), here in this process. Without PREFECT_API_URL the command
starts a temporary local Prefect server for the run (a few seconds), which a
watchdog stops even if the scan is killed; with PREFECT_API_URL set (for
example after 'make serve') the run also shows in that server's dashboard.
"""

EPILOG = """\
examples:
  valvediag scan --exports 'historian/*.csv' --loops loops.csv --db plant.duckdb --out out/
  valvediag scan --exports exports/ --loops loops.csv --db plant.duckdb --out out/ --json
  valvediag scan ... --workers 2                        # local Dask cluster, 2 processes
  valvediag scan ... --dask-address tcp://10.0.0.5:8786 --partitions /shared/parts

exit codes:
  0  the run is complete: every export was stored and every loop analysed
  2  nothing was analysed: bad arguments, another scan holds the store, a
     directory that cannot be written, no export reached the store, or a
     failed step (the run is stored as failed, with the reason); the
     outputs of the previous run are left as they were
  3  the run is partial: the outputs are written, but some export could not
     be read or all its rows were quarantined (each is named)
"""


# what the progress display calls the flow's stages (valvediag.pipelines.nightly.progress_to)
STAGE_LABELS = {"ingest": "ingesting exports", "analyse": "analysing loops"}


def register(sub):
    p = sub.add_parser("scan", help="scan a plant's loops from historian exports (the nightly "
                                    "flow, run locally)",
                       description=HELP, epilog=EPILOG,
                       formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--exports", nargs="+", required=True, metavar="PATH_OR_GLOB",
                   help="historian export files (CSV/Parquet, long or wide), directories or "
                        "quoted globs ('**' recursive)")
    p.add_argument("--loops", required=True, metavar="LOOPS_CSV",
                   help="loop registry: loop,pv_tag,op_tag,sp_tag,mv_tag,process_type,unit,"
                        "span,criticality,description,sampling")
    p.add_argument("--db", required=True, metavar="PATH",
                   help="DuckDB store, created when missing (one process may write it at a time)")
    p.add_argument("--out", required=True, metavar="DIR",
                   help="output directory for report.html, work_orders.csv and verdicts.json")
    p.add_argument("--window-hours", type=float, default=24.0, metavar="H",
                   help="analysis window ending at each loop's latest sample (default 24)")
    p.add_argument("--end", metavar="ISO8601",
                   help="common end of the window for every loop, with a UTC offset, "
                        "e.g. 2026-11-02T00:00:00+00:00 (default: each loop's latest sample)")
    p.add_argument("--method", choices=("robust", "paper"), default="robust",
                   help="Backlash Index estimator (default robust; 'paper' is the literal "
                        "procedure of Farenzena & Trierweiler 2012)")
    p.add_argument("--min-cycles", type=float, default=3.0, metavar="N",
                   help="fewest oscillation cycles for a verdict on the valve (default 3)")
    p.add_argument("--timezone", metavar="TZ",
                   help="IANA time zone of naive time stamps in the exports, e.g. Europe/Berlin "
                        "(time stamps with an offset need none)")
    p.add_argument("--processes", type=int, metavar="N",
                   help="worker processes analysing the loops (default: one per core; 0: "
                        "threads of this process; plants of under 16 loops use threads)")
    p.add_argument("--workers", type=int, metavar="N",
                   help="analyse the loops on a local Dask cluster of N worker processes "
                        "instead (default: no Dask)")
    p.add_argument("--dask-address", metavar="ADDRESS",
                   help="analyse on the Dask cluster whose scheduler is at ADDRESS, e.g. "
                        "tcp://10.0.0.5:8786 (its workers need valvediag and read access to "
                        "--partitions)")
    p.add_argument("--partitions", metavar="DIR",
                   help="where the per-loop Parquet partitions for Dask workers go (default "
                        "DB.partitions beside the store; on a cluster, a shared directory)")
    p.add_argument("--wait", type=float, default=0.0, metavar="SECONDS",
                   help="wait up to SECONDS for another scan of the same --db to finish "
                        "(default 0: fail at once with a one-line error)")
    p.add_argument("--json", action="store_true",
                   help="print verdicts.json (every loop, ranked) to stdout instead of a summary")
    p.add_argument("-v", "--verbose", action="store_true",
                   help="show Prefect's log lines (task runs, warnings, tracebacks) on stderr; "
                        "by default only the progress display and one line per warning or "
                        "error")
    p.set_defaults(func=run)


def _check_inputs(args):
    """Validate the arguments; return ``(exports, config)`` or raise CommandError."""
    from ..io.exports import expand_paths
    from ..io.registry import RegistryError, read_loops_csv
    from ..scan.types import ScanConfig

    if not os.path.isfile(args.loops):
        raise CommandError(f"--loops {args.loops}: no such file")
    try:
        read_loops_csv(args.loops)
    except RegistryError as exc:
        raise CommandError(str(exc)) from None
    files, _ = expand_paths(args.exports)    # patterns matching nothing: warned after the run
    if not files:
        raise CommandError(f"--exports {' '.join(args.exports)}: no file matches")
    if args.timezone:
        try:
            zoneinfo.ZoneInfo(args.timezone)
        except (zoneinfo.ZoneInfoNotFoundError, ValueError):
            raise CommandError(f"--timezone {args.timezone}: unknown time zone "
                               f"(use an IANA name such as Europe/Berlin)") from None
    end = None
    if args.end:
        try:
            end = dt.datetime.fromisoformat(args.end)
        except ValueError:
            raise CommandError(f"--end {args.end}: not an ISO 8601 time") from None
    try:
        config = ScanConfig(window_hours=args.window_hours, end=end, method=args.method,
                            min_cycles=args.min_cycles, timezone=args.timezone)
    except ValueError as exc:
        raise CommandError(str(exc)) from None
    out = Path(args.out)
    if out.exists() and not out.is_dir():
        raise CommandError(f"--out {args.out}: exists and is not a directory")
    if args.workers is not None and args.workers < 1:
        raise CommandError(f"--workers {args.workers}: give at least 1 worker")
    if args.processes is not None and args.processes < 0:
        raise CommandError(f"--processes {args.processes}: give 0 (threads) or more processes")
    if args.wait < 0 or args.wait != args.wait:
        raise CommandError(f"--wait {args.wait:g}: give seconds >= 0")
    if args.dask_address and "://" not in args.dask_address:
        raise CommandError(f"--dask-address {args.dask_address}: give the scheduler's address "
                           f"with its protocol, e.g. tcp://10.0.0.5:8786")
    if Path(args.db).is_dir():
        raise CommandError(f"--db {args.db}: is a directory; give a file such as "
                           f"{args.db}/valvediag.duckdb")
    return list(args.exports), config


@contextlib.contextmanager
def _scan_lock(db: str, wait: float):
    """The store's scan lock, taken once, here, by the process that runs the scan (the
    flow inside shares it); then a check that the store opens for writing. Either
    failing is one line."""
    import duckdb

    from ..store.database import Store, StoreLockedError
    from ..store.lock import ScanLock

    path = Path(db)
    try:
        path.parent.mkdir(parents=True, exist_ok=True)
        lock = ScanLock(path, timeout=wait).acquire()
    except StoreLockedError as exc:
        raise CommandError(str(exc)) from None
    except OSError as exc:
        raise CommandError(f"--db {db}: {' '.join(str(exc).split())}") from None
    with lock:
        try:
            Store(path).close()
        except StoreLockedError as exc:
            raise CommandError(str(exc)) from None
        except (duckdb.Error, OSError) as exc:
            raise CommandError(f"--db {db}: cannot open the store: "
                               f"{' '.join(str(exc).split())}") from None
        yield


def run(args) -> int:
    exports, config = _check_inputs(args)
    # no internet on plant machines: Prefect must not phone home
    os.environ.setdefault("PREFECT_SERVER_ANALYTICS_ENABLED", "false")
    os.environ.setdefault("DO_NOT_TRACK", "1")
    # the temporary server's first start creates its database: 20 s (Prefect's
    # default) is too short on a busy machine
    os.environ.setdefault("PREFECT_SERVER_EPHEMERAL_STARTUP_TIMEOUT_SECONDS", "180")
    if not args.verbose:   # Prefect's console lines, tracebacks included (the API still
        # records them, and --verbose shows them); the run's warnings and a failure are
        # printed below, once, in one line each
        os.environ.setdefault("PREFECT_LOGGING_HANDLERS_CONSOLE_LEVEL", "CRITICAL")
    from valvediag.pipelines.nightly import nightly_scan, progress_to
    from valvediag.pipelines.runners import temporary_api

    from .progress import StageProgress

    stages = StageProgress(STAGE_LABELS)
    with _scan_lock(args.db, args.wait), stages, progress_to(stages), \
            temporary_api():
        state = nightly_scan(exports=exports, loops=args.loops, db=args.db, out=args.out,
                             window_hours=config.window_hours, method=config.method,
                             min_cycles=config.min_cycles, timezone=config.timezone,
                             end=config.end, workers=args.workers,
                             dask_address=args.dask_address, partitions=args.partitions,
                             wait_s=args.wait, processes=args.processes,
                             return_state=True)
    if not state.is_completed():
        exc = state.result(raise_on_failure=False)
        detail = one_line(exc) if isinstance(exc, BaseException) else (state.message or state.name)
        raise CommandError(f"the scan failed: {detail}")
    summary = state.result()
    if args.json:
        sys.stdout.write(Path(summary["outputs"]["verdicts"]).read_text(encoding="utf-8"))
        sys.stdout.write("\n")
    else:
        _print_summary(summary)
    for line in summary["ingest"]["errors"] + summary["registry_problems"]:
        print(f"valvediag scan: warning: {line}", file=sys.stderr)
    for line in summary["ingest"]["quarantined"]:
        print(f"valvediag scan: rows quarantined: {line}", file=sys.stderr)
    if summary["status"] != "complete":
        print(f"valvediag scan: the run {summary['run_id']} is {summary['status']}: "
              f"{summary['status_note']}", file=sys.stderr)
        return EXIT_PARTIAL
    return 0


def _print_summary(summary: dict) -> None:
    verdicts = json.loads(Path(summary["outputs"]["verdicts"]).read_text(encoding="utf-8"))
    counts = ", ".join(f"{v} {n}" for v, n in summary["counts"].items())
    print(f"run {summary['run_id']}: {summary['loops']} loops ({counts})")
    ranked = [v for v in verdicts["loops"] if v.get("rank") is not None]
    if ranked:
        new = set(summary["new_faults"])
        print(f"\n{'rank':>4s}  {'loop':16s} {'verdict':18s} {'conf':>5s} {'severity':>8s}")
        for v in ranked[:20]:
            print(f"{v['rank']:4d}  {v['loop']:16s} {v['verdict']:18s} {v['confidence']:5.2f} "
                  f"{v['severity']:8.3f}{'  new' if v['loop'] in new else ''}")
        if len(ranked) > 20:
            print(f"      ... {len(ranked) - 20} more in the report")
    else:
        print("no loop needs action")
    out = summary["outputs"]
    print(f"\nreport       {out['report']}\nwork orders  {out['work_orders']}\n"
          f"verdicts     {out['verdicts']}")
