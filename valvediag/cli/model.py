"""``valvediag model``: the model workbench on a single-loop CSV file."""
from __future__ import annotations

import json
from pathlib import Path

from ..plain import finite_or_none
from . import CommandError

HELP = """\
Compare a physical loop model with the measurements of one loop, see where it
fails, learn which physical effect is missing, add it and watch the error
fall. The model is driven by the measured OP and predicts the PV; it is made
of named effects (deadband, stiction, saturation, characteristic, dead_time,
lag, bias, drift, oscillating_load) on top of the plant (integrating or
self-regulating). It is fitted on
training time blocks and scored on held-out blocks.
"""

EFFECTS_HELP = ("comma-separated effects: deadband, stiction, saturation, characteristic, "
                "dead_time, lag, bias, drift, oscillating_load (see 'valvediag model effects')")


def _common(p, *, effects_default: str, effects_help: str):
    p.add_argument("file", metavar="FILE", help="single-loop CSV (timestamp,pv,op[,sp,mv])")
    p.add_argument("--effects", default=effects_default, metavar="A,B", help=effects_help)
    p.add_argument("--process-type", choices=("integrating", "self-regulating"),
                   default="integrating", help="plant: integrating g/s (default) or K/(tau s+1)")
    p.add_argument("--horizon", type=int, default=None, metavar="N",
                   help="re-initialise the prediction every N samples (default: a quarter of "
                        "the OP period, 30-600)")
    p.add_argument("--blocks", type=int, default=9,
                   help="alternating training/held-out time blocks (odd, default 9)")
    p.add_argument("--reinit", choices=("fit", "measured"), default="fit",
                   help="start each segment's prediction from its best initial state (default; "
                        "robust to PV noise) or from the measured PV")
    p.add_argument("--pv-points", choices=("all", "stored"), default="all",
                   help="PV samples the fit scores: every one (default), or only those the "
                        "historian stored, for a PV stored compressed and read back by straight "
                        "lines between its stored points (the lines cut its turns short)")
    for role in ("timestamp", "pv", "op", "sp"):
        p.add_argument(f"--{role}-column", metavar="NAME",
                       help=f"name of the {role} column if it is not '{role}'")


def register(sub):
    p = sub.add_parser("model", help="model workbench: fit, diagnose and report a loop model",
                       description=HELP)
    msub = p.add_subparsers(dest="model_command", metavar="SUBCOMMAND")
    p.set_defaults(func=lambda args: _no_sub(p))

    f = msub.add_parser("fit", help="fit a model with the given effects",
                        description="Fit a loop model with the given effects to FILE and print "
                                    "its parameters, held-out fit %, held-out RMSE and BIC.")
    _common(f, effects_default="", effects_help=EFFECTS_HELP + " (default: the plant alone)")
    f.add_argument("--json", action="store_true", help="print one JSON object")
    f.set_defaults(func=run_fit)

    d = msub.add_parser("diagnose", help="rank the effects missing from a starting model",
                        description="Fit the starting model, show where it fails, and rank the "
                                    "effects it lacks: each is added, refitted and scored on "
                                    "held-out data; it is accepted when both the held-out RMSE "
                                    "and the BIC fall.")
    _common(d, effects_default="", effects_help="starting model: " + EFFECTS_HELP
                                                + " (default: the plant alone)")
    d.add_argument("--json", action="store_true",
                   help='print {"base": {...}, "suggestions": [...], "rivals": [...]}, best first')
    d.set_defaults(func=run_diagnose)

    r = msub.add_parser("report", help="write an HTML page: before/after, residuals, ladder",
                        description="Greedy forward selection from the starting model, then one "
                                    "self-contained HTML page with the overlay before and "
                                    "after, where the model fails, the evidence for each "
                                    "candidate effect, the error ladder and the recommendation.")
    _common(r, effects_default="", effects_help="starting model: " + EFFECTS_HELP
                                                + " (default: the plant alone)")
    r.add_argument("--out", required=True, metavar="DIR", help="output directory")
    r.add_argument("--max-steps", type=int, default=None, metavar="N",
                   help="add at most N effects")
    r.set_defaults(func=run_report)

    e = msub.add_parser("effects", help="list the effects and their parameters",
                        description="List the named effects, their parameters with units and "
                                    "ranges, and the residual signature of each.")
    e.add_argument("--json", action="store_true", help="print JSON")
    e.set_defaults(func=run_effects)


def _no_sub(p) -> int:
    p.print_help()
    return 0


def _load(args):
    """Read FILE and prepare it; one-line errors naming the file."""
    from ..io.loopfile import LoopFileError, read_loop_csv
    from ..workbench import WorkbenchDataError, check_effects, prepare_loop

    try:
        effects = check_effects(args.effects)
    except ValueError as exc:
        raise CommandError(f"--effects: {exc}") from None
    columns = {r: getattr(args, f"{r}_column") for r in ("timestamp", "pv", "op", "sp")
               if getattr(args, f"{r}_column")}
    try:
        rec, meta = read_loop_csv(args.file, columns=columns or None)
    except LoopFileError as exc:
        raise CommandError(str(exc)) from None
    try:
        data = prepare_loop(rec.pv, rec.op, rec.sample_time, sp=rec.sp,
                            horizon=args.horizon if args.horizon else "auto", blocks=args.blocks,
                            name=Path(args.file).name, reinit=args.reinit,
                            pv_points=args.pv_points)
    except WorkbenchDataError as exc:
        raise CommandError(f"{args.file}: {exc}") from None
    return data, effects, meta


def run_fit(args) -> int:
    from ..workbench import LoopModel

    data, effects, _ = _load(args)
    fit = LoopModel(effects, args.process_type).fit(data)
    if args.json:
        doc = {"file": str(args.file), **fit.to_dict(),
               "units": dict(fit.units),
               "derived": {k: finite_or_none(v, 6) for k, v in fit.derived.items()},
               "fit_pct_train": finite_or_none(fit.fit_pct_train, 6),
               "train_rmse": finite_or_none(fit.train_rmse, 6),
               "n_params": fit.n_params, "horizon": data.horizon,
               "sample_time": data.sample_time}
        doc["params"] = {k: finite_or_none(v, 6) for k, v in fit.params.items()}
        print(json.dumps(doc, indent=2))
        return 0
    print(f"{args.file}")
    print(fit.summary())
    for k, v in fit.derived.items():
        print(f"  ({k} = {v if isinstance(v, str) else format(v, '.5g')})")
    return 0


def run_diagnose(args) -> int:
    from ..workbench import LoopModel, suggest_effects

    data, effects, _ = _load(args)
    sug = suggest_effects(LoopModel(effects, args.process_type).fit(data))
    if args.json:
        print(json.dumps(sug.to_dict(), indent=2))
        return 0
    print(f"{args.file}")
    print(sug.diagnosis.summary())
    print()
    print(sug.table())
    best = sug.best
    print()
    if best is None:
        print("No effect lowers both the held-out error and the BIC: the model is complete "
              "for these data.")
    else:
        ps = ", ".join(f"{k}={v:.4g}" for k, v in best.params.items())
        print(f"Add '{best.effect}': held-out RMSE falls {100 * best.gain:.0f} % ({ps}).")
    return 0


def run_report(args) -> int:
    from ..workbench import forward_select
    from ..workbench.report import write_workbench_report

    data, effects, meta = _load(args)
    lad = forward_select(data, effects, process_type=args.process_type, max_steps=args.max_steps)
    out = Path(args.out) / f"{Path(args.file).stem}.workbench.html"
    extra = {}
    if meta.get("non_numeric"):
        extra["non-numeric values ignored"] = ", ".join(f"{k} {v}" for k, v in meta["non_numeric"].items())
    if meta.get("resampled"):
        extra["note"] = "irregular time stamps were interpolated onto the median spacing by the reader"
    try:
        path = write_workbench_report(lad, out, name=Path(args.file).name, meta=extra)
    except OSError as exc:
        raise CommandError(f"{out}: cannot write the report ({exc.strerror or exc})") from None
    print(lad.table())
    print(f"\nreport: {path}")
    return 0


def run_effects(args) -> int:
    from ..workbench import EFFECTS, PLANT_PARAMS

    if args.json:
        doc = {name: {"stage": e.stage, "description": e.description, "signature": e.signature,
                      "params": [dict(name=p.name, unit=p.unit, bounds=p.bounds, kind=p.kind,
                                      description=p.description) for p in e.params]}
               for name, e in EFFECTS.items()}
        doc["plant"] = {k: [dict(name=p.name, unit=p.unit, bounds=p.bounds, kind=p.kind,
                                 description=p.description) for p in v]
                        for k, v in PLANT_PARAMS.items()}
        print(json.dumps(doc, indent=2))
        return 0
    for name, e in EFFECTS.items():
        print(f"{name} ({e.stage}): {e.description}")
        for p in e.params:
            print(f"    {p.name} [{p.unit}], {p.kind}, {p.bounds}: {p.description}")
        print(f"    missing -> {e.signature}")
    for k, v in PLANT_PARAMS.items():
        print(f"plant, {k}: " + "; ".join(f"{p.name} [{p.unit}] ({p.kind})" for p in v))
    return 0
