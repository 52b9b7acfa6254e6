"""``valvediag synth-plant``: write a synthetic plant (historian exports with known truth)."""
from __future__ import annotations

import argparse
import json
import sys

from ..plain import one_line
from . import CommandError

DESCRIPTION = """\
Simulate a plant of control loops and write what a process historian would
export, together with the loop registry and the answer key:

  DIR/exports/   historian exports, one file per group of loops and day
  DIR/loops.csv  the loop registry (loop,pv_tag,op_tag,sp_tag,mv_tag,...)
  DIR/truth.csv  the true verdict of every loop (column truth_verdict)

About 20 % of the loops have a sticky valve, 15 % a loose one (backlash),
10 % a linear oscillation, 7.5 % a sticky valve on a self-regulating process,
a third are healthy and 15 % have unusable data. The records carry digital
states, gaps, and exception and swinging-door compression.
The output is a deterministic function of the options. Use it to try the scan:

  valvediag synth-plant --loops 40 --days 1 --sample-time 5 --out plant
"""


def _positive(kind):
    def parse(text):
        try:
            value = kind(text)
        except ValueError:
            raise argparse.ArgumentTypeError(f"not a number: {text!r}") from None
        if not value > 0:
            raise argparse.ArgumentTypeError(f"must be > 0, got {text}")
        return value
    return parse


def register(subparsers) -> None:
    from ..synth.plant import FORMATS

    p = subparsers.add_parser(
        "synth-plant", help="write a synthetic plant: historian exports, loops.csv, truth.csv",
        description=DESCRIPTION, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--loops", type=_positive(int), required=True, metavar="N",
                   help="number of control loops")
    p.add_argument("--days", type=_positive(float), required=True, metavar="D",
                   help="record length [days]")
    p.add_argument("--sample-time", type=_positive(float), required=True, metavar="S",
                   help="historian sample time [s] of uncompressed tags")
    p.add_argument("--out", required=True, metavar="DIR",
                   help="output directory (created; earlier exports there are replaced)")
    p.add_argument("--seed", type=int, default=0, metavar="N", help="random seed (default 0)")
    p.add_argument("--formats", nargs="+", choices=FORMATS, default=["long-csv"],
                   metavar="FORMAT",
                   help=f"export formats, one or more of {', '.join(FORMATS)} "
                        f"(default long-csv); with several, each loop goes to one of them")
    p.add_argument("--start", default="2026-11-01T00:00:00Z", metavar="ISO",
                   help="first time stamp, ISO 8601 (default 2026-11-01T00:00:00Z)")
    p.add_argument("--timezone", default="UTC", metavar="ZONE",
                   help="IANA time zone of the written time stamps (default UTC; the UTC "
                        "offset is always written)")
    p.add_argument("--json", action="store_true",
                   help="print a JSON summary (files and truth counts) instead of text")
    p.add_argument("--quiet", action="store_true", help="no progress bar")
    p.set_defaults(func=run)


def run(args) -> int:
    from ..synth.plant import synth_plant
    from .progress import progress_bar

    try:
        with progress_bar("synth-plant", enabled=not (args.quiet or args.json)) as bar:
            plant = synth_plant(args.loops, args.days, args.sample_time, args.out,
                                seed=args.seed, formats=tuple(args.formats), start=args.start,
                                timezone=args.timezone, progress=bar)
    except ValueError as exc:
        raise CommandError(one_line(exc)) from None
    except OSError as exc:
        raise CommandError(f"{args.out}: {exc.strerror or exc}") from None
    counts = dict(plant.truth.group_by("truth_verdict").len().sort("truth_verdict").iter_rows())
    if args.json:
        json.dump({"out_dir": str(plant.out_dir), "loops_csv": str(plant.loops_csv),
                   "truth_csv": str(plant.truth_csv), "exports": [str(p) for p in plant.exports],
                   "loops": args.loops, "days": plant.days, "sample_time": plant.sample_time,
                   "seed": plant.seed, "truth_counts": counts}, sys.stdout, indent=1)
        print()
        return 0
    print(f"wrote {len(plant.exports)} export file(s) to {plant.out_dir / 'exports'}")
    print(f"loop registry: {plant.loops_csv}")
    print(f"answer key:    {plant.truth_csv}")
    for verdict, n in counts.items():
        print(f"  {verdict:<20} {n:>5}")
    return 0
