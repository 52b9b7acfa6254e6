"""``valvediag bi``: classify single-loop CSV files."""
from __future__ import annotations

import json

from ..analysis.classify import classify_loop
from ..io.loopfile import LoopFileError, read_loop_csv
from ..plain import finite_or_none

HELP = """\
Classify one or more single-loop CSV files (columns timestamp,pv,op[,sp,mv];
timestamp ISO 8601 or seconds). For each file valvediag finds the oscillation,
checks that it is regular and caused by a valve nonlinearity, and computes the
Backlash Index (BI): stiction (sharp peaks), backlash (rounded peaks after
straight ramps) or undecided. Where the file has a valve position column (mv),
the position is read against the OP as well: a position that follows the OP
clears the valve, one that lags and jumps names a sticky valve. A file that
cannot be analysed gets the verdict insufficient-data with the reason and does
not stop the others.

exit codes: 0 when at least one file was read, 2 when none could be (each
file's reason is printed).
"""


def register(sub):
    p = sub.add_parser("bi", help="Backlash Index and verdict for single-loop CSV files",
                       description=HELP)
    p.add_argument("files", nargs="+", metavar="FILE", help="single-loop CSV file(s)")
    p.add_argument("--method", choices=("robust", "paper"), default="robust",
                   help="BI estimator: 'robust' (default; for plant data) or 'paper' "
                        "(the literal procedure of Farenzena & Trierweiler 2012)")
    p.add_argument("--process-type", choices=("integrating", "self-regulating", "unknown"),
                   default="integrating",
                   help="process type of the loop(s) (default integrating; 'unknown' runs a "
                        "data test)")
    p.add_argument("--sampling", choices=("point", "average"), default="point",
                   help="what each PV sample is: 'point', its value at the time stamp "
                        "(default), or 'average', its mean over the sample time (a "
                        "historian's average export, whose averaging would otherwise read "
                        "as backlash)")
    p.add_argument("--min-cycles", type=float, default=3.0,
                   help="fewest oscillation cycles for a verdict on the valve (default 3)")
    for role in ("timestamp", "pv", "op", "sp", "mv"):
        p.add_argument(f"--{role}-column", metavar="NAME",
                       help=f"name of the {role} column if it is not '{role}'")
    p.add_argument("--json", action="store_true", help="print one JSON list, an object per file")
    p.set_defaults(func=run)


def classify_file(path, *, method="robust", process_type="integrating", min_cycles=3.0,
                  columns=None, sampling="point") -> dict:
    """Verdict for one file as the JSON object of ``valvediag bi --json``."""
    return _classify(path, method, process_type, min_cycles, columns, sampling)[0]


def _classify(path, method, process_type, min_cycles, columns,
              sampling="point") -> tuple[dict, bool]:
    """:func:`classify_file`'s row, and whether the file could be read."""
    try:
        rec, meta = read_loop_csv(path, columns=columns)
    except LoopFileError as exc:
        return {"file": str(path), "verdict": "insufficient-data", "bi": None, "cycles": 0,
                "period_s": None, "confidence": None, "reason": str(exc)}, False
    d = classify_loop(rec.pv, rec.op, rec.sp, sample_time=rec.sample_time,
                      process_type=process_type, method=method, min_cycles=min_cycles, mv=rec.mv,
                      pv_averaged=sampling == "average")
    reason = d.reason
    if meta["non_numeric"]:
        reason += "; non-numeric values ignored: " + ", ".join(f"{k} {v}" for k, v in meta["non_numeric"].items())
    return {"file": str(path), "verdict": d.verdict, "bi": finite_or_none(d.bi, 3), "cycles": finite_or_none(d.cycles, 1),
            "period_s": finite_or_none(d.period, 4), "confidence": finite_or_none(d.confidence, 2), "reason": reason}, True


def run(args) -> int:
    columns = {r: getattr(args, f"{r}_column") for r in ("timestamp", "pv", "op", "sp", "mv")
               if getattr(args, f"{r}_column")}
    done = [_classify(f, args.method, args.process_type, args.min_cycles, columns or None,
                      args.sampling) for f in args.files]
    rows = [row for row, _ in done]
    # every file unreadable: nothing was analysed, which must not exit 0
    status = 0 if any(read for _, read in done) else 2
    if args.json:
        print(json.dumps(rows, indent=2))
        return status
    w = max(len(r["file"]) for r in rows)
    print(f"{'file':{w}s}  {'verdict':18s} {'BI':>6s} {'cycles':>6s} {'period [s]':>10s} {'conf':>5s}")
    for r in rows:
        fmt = lambda v, f: format(v, f) if v is not None else "-"
        print(f"{r['file']:{w}s}  {r['verdict']:18s} {fmt(r['bi'], '6.2f'):>6s} "
              f"{fmt(r['cycles'], '6.1f'):>6s} {fmt(r['period_s'], '10.4g'):>10s} "
              f"{fmt(r['confidence'], '5.2f'):>5s}")
        print(f"{'':{w}s}  {r['reason']}")
    return status
