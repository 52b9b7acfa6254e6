"""``valvediag reproduce-paper``: Tables 1-3 of Farenzena & Trierweiler (2012)."""
from __future__ import annotations

import json
from pathlib import Path

from ..paper.tables import reproduce_paper
from . import CommandError

HELP = """\
Run the simulation grids of Tables 1-3 of Farenzena & Trierweiler (2012) exactly
as printed (Table 1: 73,920 stiction scenarios, not the 52,800 the paper states;
Table 2: 13,440 backlash scenarios; Table 3: 840 backlash scenarios over seven
sampling times) and print the share of each verdict beside the paper's figures.
"""


def register(sub):
    p = sub.add_parser("reproduce-paper", help="reproduce Tables 1-3 of the paper",
                       description=HELP)
    p.add_argument("--method", choices=("paper", "robust"), default="paper",
                   help="BI estimator (default 'paper', the literal procedure)")
    p.add_argument("--json", metavar="PATH", help="also write the results as JSON to PATH")
    p.add_argument("--quiet", action="store_true", help="no progress bar")
    p.set_defaults(func=run)


def run(args) -> int:
    if args.json:
        target = Path(args.json)
        if target.parent and not target.parent.exists():
            raise CommandError(f"cannot write {target}: directory {target.parent} does not exist")
    from .progress import progress_bar

    with progress_bar("simulating scenarios", enabled=not args.quiet) as bar:
        res = reproduce_paper(args.method, progress=bar)
    print(res.report())
    if args.json:
        Path(args.json).write_text(json.dumps(res.to_json(), indent=2) + "\n")
        print(f"\nwritten: {args.json}")
    return 0
