"""Benchmark: plant scale, 1,000 loop-days at 1 s through the nightly scan, end to end.

Targets: ingest and scan 1,000 loops of one day at 1 s (PV, OP and SP every
second would be 259.2 million samples) in at most 5 minutes, with at most
4 GB of memory. Also measures the speed-up of the per-loop analysis on a
local Dask cluster of 2 worker processes against 1 (``valvediag scan
--workers N``).

1. **Plant** (not timed). :func:`valvediag.synth.plant.synth_plant` writes a
   synthetic plant as Parquet exports (long, one file per 50 loops and day)
   into ``--plant-dir`` (default ``out/bench_plant/plant-<loops>x<days>d-<ts>s``
   in the repository, git-ignored). A finished plant is marked by
   ``bench_plant.json`` there and reused by later runs. The synthetic
   historian compresses like a real one (swinging door and exception
   reporting on some PVs, set points stored on change and hourly), so fewer
   rows are stored than the nominal 3 x 86,400 per loop-day; both counts are
   printed.
2. **End to end** (timed). A child process runs the Prefect flow
   ``nightly-scan`` (:func:`valvediag.pipelines.nightly.nightly_scan`, the flow that
   ``valvediag scan`` and the nightly deployment run) with the same
   arguments as ``valvediag scan --exports <plant>/exports --loops
   <plant>/loops.csv --db <fresh store> --out <dir>``: ingest into a fresh
   DuckDB store, plan, analyse every loop (batches of loops on worker
   processes of the flow, the default; ``--workers N`` for a local Dask
   cluster), rank, persist, write
   the outputs and artifacts. Stage times come from the flow's progress
   reports (:func:`valvediag.pipelines.nightly.progress_to`): ingest, then plan +
   analysis (including the start of the worker processes), then rank +
   persist + outputs. The Prefect API server the flow reports to is started
   in the child before the clock starts (its start-up is printed, not timed)
   and is private to the benchmark (its ``PREFECT_HOME`` is in the work
   directory), so runs never land in a user's Prefect server.
   The flow analyses on :data:`valvediag.pipelines.runners.ANALYSIS_PROCESSES` worker
   processes (one per core), :func:`valvediag.pipelines.runners.loop_batches` loops
   per task.
3. **Dask speed-up** (timed). The first ``--speedup-loops`` loops of the
   registry are scanned again, on the store of step 2 (the exports are
   already ingested and are skipped), once with ``workers=1`` and once with
   ``workers=2``: the flow's real DaskTaskRunner path (partitions exported
   to Parquet, a LocalCluster of single-threaded worker processes, one
   ``analyse-partitions`` task per batch of loops). Printed: the analysis stage (plan,
   partition export, cluster start and the tasks) and the tasks alone.

Peak memory is sampled every 0.2 s as the sum of the resident set sizes of
the child and all its descendants (the Prefect server, Dask scheduler, nanny
and worker processes), with psutil (``/proc`` without it); pages shared by
several processes count in each, so the figure is an upper bound. The largest
single process (``getrusage`` maxrss) is printed too.

The store and outputs go to ``--work-dir`` (default
``out/bench_plant/run-<loops>x<days>d-<ts>s``); the store is deleted at the
end unless ``--keep``. A lock file in both directories keeps two runs apart.
Quick run: ``--loops 50 --speedup-loops 20`` (about 2 minutes). The full
default takes about 10 minutes on two cores (the README has the figures),
plus one minute to generate the plant the first time (647 MB of Parquet;
the store takes 530 MB). Exits 0 when the runs complete (whether or not the targets
are met), 1 when a run fails or another run holds the directories, 2 on bad
arguments.
"""
from __future__ import annotations

import argparse
import fcntl
import json
import os
import resource
import shutil
import signal
import subprocess
import sys
import threading
import time
from pathlib import Path

REPO = Path(__file__).resolve().parent.parent
TARGET_S = 300.0
TARGET_MB = 4096.0
MARKER = "bench_plant.json"
# Parquet export plus store, per nominal sample (measured: ~4 + ~4 bytes); with margin
_BYTES_PER_SAMPLE = 20


# ------------------------------------------------------------------ memory
def _rss_psutil(pid: int) -> tuple[float, int]:
    """Resident memory [MB] and threads of ``pid`` and its descendants."""
    import psutil

    try:
        root = psutil.Process(pid)
        procs = [root] + root.children(recursive=True)
    except psutil.Error:
        return 0.0, 0
    total = threads = 0
    for p in procs:
        try:
            total += p.memory_info().rss
            threads += p.num_threads()
        except psutil.Error:
            pass
    return total / 2**20, threads


def _rss_proc(pid: int) -> tuple[float, int]:
    """Sum of VmRSS [MB] and of Threads of ``pid`` and its descendants, from /proc."""
    parent = {}
    for d in os.listdir("/proc"):
        if d.isdigit():
            try:
                with open(f"/proc/{d}/stat") as fh:
                    parent[int(d)] = int(fh.read().rsplit(")", 1)[1].split()[1])
            except (OSError, ValueError, IndexError):
                pass
    tree, todo = set(), [pid]
    while todo:
        p = todo.pop()
        tree.add(p)
        todo += [c for c, pp in parent.items() if pp == p and c not in tree]
    total = threads = 0
    for p in tree:
        try:
            with open(f"/proc/{p}/status") as fh:
                for line in fh:
                    if line.startswith("VmRSS:"):
                        total += int(line.split()[1]) * 1024
                    elif line.startswith("Threads:"):
                        threads += int(line.split()[1])
        except OSError:
            pass
    return total / 2**20, threads


class TreeMemory:
    """Sample the resident memory of a process and its descendants in a thread."""

    def __init__(self, pid: int, interval: float = 0.2):
        try:
            import psutil  # noqa: F401
            self._rss = _rss_psutil
            self.method = "psutil"
        except ImportError:
            self._rss = _rss_proc
            self.method = "/proc"
        self.pid, self.interval = pid, interval
        self.samples: list[tuple[float, float, int]] = []   # (monotonic time, MB, threads)
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._run, daemon=True)
        self._thread.start()

    def _run(self):
        while not self._stop.is_set():
            self.samples.append((time.monotonic(), *self._rss(self.pid)))
            self._stop.wait(self.interval)

    def stop(self):
        self._stop.set()
        self._thread.join()

    def peak(self, t0: float | None = None, t1: float | None = None) -> float:
        vals = [mb for t, mb, _ in self.samples
                if (t0 is None or t >= t0) and (t1 is None or t <= t1)]
        return max(vals, default=0.0)

    def peak_threads(self) -> int:
        return max((k for _, _, k in self.samples), default=0)


# ------------------------------------------------------------------ child: one flow run
def _child(spec_path: str) -> None:
    """Run the nightly-scan flow once as ``valvediag scan`` does; write JSON figures."""
    spec = json.loads(Path(spec_path).read_text())
    os.environ.setdefault("PREFECT_SERVER_ANALYTICS_ENABLED", "false")
    os.environ.setdefault("DO_NOT_TRACK", "1")
    os.environ.setdefault("MPLBACKEND", "Agg")
    os.environ.setdefault("PREFECT_LOGGING_HANDLERS_CONSOLE_LEVEL", "ERROR")
    os.environ.pop("PREFECT_API_URL", None)
    from prefect.logging.handlers import APILogHandler
    from prefect.server.api.server import SubprocessASGIServer
    from prefect.settings import PREFECT_API_URL, temporary_settings
    from valvediag.pipelines.nightly import nightly_scan, progress_to

    events: list[tuple[str, int, int, float]] = []
    shown: dict[str, int] = {}

    def record(stage: str, done: int, total: int) -> None:
        events.append((stage, done, total, time.monotonic()))
        step = max(total // 10, 1)
        if total and (done == total or done // step > shown.get(stage, -1)):
            shown[stage] = done // step
            unit = "files" if stage == "ingest" else "loops"
            print(f"    {spec['label']}: {stage} {done}/{total} {unit}", flush=True)

    t = time.monotonic()
    server = SubprocessASGIServer()
    server.start(timeout=180)
    server_s = time.monotonic() - t
    os.environ["PREFECT_API_URL"] = server.api_url   # for Dask worker processes
    try:
        with temporary_settings(updates={PREFECT_API_URL: server.api_url}), \
                progress_to(record):
            t0 = time.monotonic()
            state = nightly_scan(exports=spec["exports"], loops=spec["loops"], db=spec["db"],
                                 out=spec["out"], workers=spec["workers"], return_state=True)
            t1 = time.monotonic()
            ok = state.is_completed()
            summary = state.result() if ok else None
            error = None if ok else " ".join(str(state.result(raise_on_failure=False)).split())
        APILogHandler().flush()   # the run's last log lines, before the server goes
    finally:
        os.environ.pop("PREFECT_API_URL", None)
        server.stop()
    self_mb = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024
    kids_mb = resource.getrusage(resource.RUSAGE_CHILDREN).ru_maxrss / 1024
    Path(spec["result"]).write_text(json.dumps({
        "ok": ok, "error": error, "t0": t0, "t1": t1, "server_s": server_s,
        "events": events, "summary": summary, "maxrss_mb": max(self_mb, kids_mb)}, default=str))


# ------------------------------------------------------------------ parent
def _stage(events, stage: str) -> tuple[float | None, float | None]:
    """First and last report time of a stage (the last one with done == total)."""
    ts = [e for e in events if e[0] == stage]
    if not ts:
        return None, None
    done = [e[3] for e in ts if e[1] == e[2]]
    return ts[0][3], (done[-1] if done else ts[-1][3])


def _run_flow(label: str, work: Path, exports: Path, loops_csv: Path, db: Path, out: Path,
              workers: int | None) -> dict:
    """One flow run in a child process, memory sampled over its process tree."""
    spec = {"label": label, "exports": str(exports), "loops": str(loops_csv), "db": str(db),
            "out": str(out), "workers": workers, "result": str(work / f"{label}.result.json")}
    spec_path = work / f"{label}.spec.json"
    spec_path.write_text(json.dumps(spec))
    Path(spec["result"]).unlink(missing_ok=True)
    log = work / f"{label}.log"
    env = dict(os.environ, PREFECT_HOME=str(work / "prefect-home"), PYTHONUNBUFFERED="1")
    env["PYTHONPATH"] = os.pathsep.join(filter(None, [str(REPO), env.get("PYTHONPATH")]))
    with open(log, "wb") as err:
        proc = subprocess.Popen([sys.executable, __file__, "--child", str(spec_path)],
                                cwd=REPO, env=env, stderr=err, stdin=subprocess.DEVNULL,
                                start_new_session=True)
        mem = TreeMemory(proc.pid)
        try:
            rc = proc.wait()
        except BaseException:          # Ctrl-C: end the child's process group (ours)
            _end_group(proc)
            raise
        finally:
            mem.stop()
    res = json.loads(Path(spec["result"]).read_text()) if Path(spec["result"]).exists() else None
    if rc != 0 or res is None or not res["ok"]:
        detail = (res or {}).get("error") or f"exit code {rc}"
        tail = "\n".join(log.read_text(errors="replace").splitlines()[-15:])
        raise RuntimeError(f"the {label} run failed: {detail}\n  last lines of {log}:\n{tail}")
    res["mem"], res["mem_method"] = mem, mem.method
    return res


def _end_group(proc: subprocess.Popen) -> None:
    for sig in (signal.SIGTERM, signal.SIGKILL):
        try:
            os.killpg(proc.pid, sig)
        except ProcessLookupError:
            return
        try:
            proc.wait(timeout=10)
            return
        except subprocess.TimeoutExpired:
            continue


def _fresh_store(db: Path) -> None:
    for p in (db, db.with_name(db.name + ".wal"), db.with_name(db.name + ".scan.lock")):
        p.unlink(missing_ok=True)
    shutil.rmtree(db.with_name(db.name + ".partitions"), ignore_errors=True)


def _ensure_plant(plant_dir: Path, loops: int, days: float, st: float, seed: int) -> dict:
    """Generate the plant unless a finished one with these parameters is there."""
    want = {"loops": loops, "days": days, "sample_time": st, "seed": seed, "format": "parquet"}
    marker = plant_dir / MARKER
    if marker.exists():
        try:
            have = json.loads(marker.read_text())
        except ValueError:
            have = {}
        if {k: have.get(k) for k in want} == want and (plant_dir / "loops.csv").exists():
            print(f"plant: reusing {plant_dir} (generated in {have.get('generate_s', 0):.0f} s "
                  f"earlier; delete it to regenerate)", flush=True)
            return have
        print(f"plant: {plant_dir} holds another plant; regenerating", flush=True)
    marker.unlink(missing_ok=True)
    from valvediag.synth.plant import synth_plant

    print(f"plant: generating {loops} loops x {days:g} d at {st:g} s into {plant_dir} "
          f"(not timed) ...", flush=True)
    shown = [-1]

    def progress(done, total):
        if done * 10 // total > shown[0]:
            shown[0] = done * 10 // total
            print(f"    generate {done}/{total}", flush=True)

    t = time.perf_counter()
    try:
        plant = synth_plant(loops, days, st, plant_dir, seed=seed, formats=("parquet",),
                            progress=progress)
    except ValueError as exc:
        raise RuntimeError(f"cannot generate the plant: {exc}") from None
    gen_s = time.perf_counter() - t
    size = sum(p.stat().st_size for p in plant.exports)
    info = {**want, "generate_s": gen_s, "files": len(plant.exports), "bytes": size}
    marker.write_text(json.dumps(info, indent=1))
    print(f"plant: generated in {gen_s:.0f} s: {len(plant.exports)} Parquet files, "
          f"{size / 1e6:,.0f} MB", flush=True)
    return info


def _subset_loops(loops_csv: Path, n: int, dest: Path) -> int:
    import polars as pl

    frame = pl.read_csv(loops_csv, infer_schema=False)
    frame.head(n).write_csv(dest)
    return min(n, frame.height)


def _lock(directory: Path):
    """Hold ``directory/.bench_plant.lock`` (flock) so two benchmarks never share it."""
    fd = os.open(directory / ".bench_plant.lock", os.O_RDWR | os.O_CREAT, 0o644)
    try:
        fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
    except BlockingIOError:
        os.close(fd)
        raise RuntimeError(f"{directory} is in use by another bench_plant run; wait for it "
                           f"or give another --plant-dir/--work-dir") from None
    return fd


def _loadavg() -> str:
    try:
        return " ".join(f"{x:.2f}" for x in os.getloadavg())
    except OSError:
        return "n/a"


def _fmt_target(value: float, target: float) -> str:
    return "met" if value <= target else "MISSED"


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0],
                                     formatter_class=argparse.RawDescriptionHelpFormatter,
                                     epilog="defaults are the real target: 1,000 loops x 1 d "
                                            "at 1 s; quick run: --loops 50 --speedup-loops 20")
    parser.add_argument("--loops", type=int, default=1000, help="loops (default 1000)")
    parser.add_argument("--days", type=float, default=1.0, help="days per loop (default 1)")
    parser.add_argument("--sample-time", type=float, default=1.0, metavar="S",
                        help="historian sample time [s] (default 1)")
    parser.add_argument("--seed", type=int, default=1, help="plant seed (default 1)")
    parser.add_argument("--plant-dir", metavar="DIR",
                        help="where the generated plant is cached (default "
                             "out/bench_plant/plant-<loops>x<days>d-<ts>s)")
    parser.add_argument("--work-dir", metavar="DIR",
                        help="store, outputs and logs (default out/bench_plant/run-...)")
    parser.add_argument("--workers", type=int, metavar="N",
                        help="end-to-end run on a local Dask cluster of N workers (default: "
                             "worker processes, as 'valvediag scan' without --workers)")
    parser.add_argument("--speedup-loops", type=int, default=300, metavar="N",
                        help="loops of the Dask 1-vs-2-worker comparison (default 300; 0 skips)")
    parser.add_argument("--keep", action="store_true", help="keep the store afterwards")
    parser.add_argument("--json", action="store_true", help="also print the figures as JSON")
    parser.add_argument("--child", metavar="SPEC", help=argparse.SUPPRESS)
    args = parser.parse_args(argv)
    if args.child:
        _child(args.child)
        return 0
    if args.loops < 1 or args.days <= 0 or args.sample_time <= 0 or args.speedup_loops < 0:
        parser.error("--loops >= 1, --days > 0, --sample-time > 0 and --speedup-loops >= 0")
    if args.workers is not None and args.workers < 1:
        parser.error("--workers must be >= 1")
    try:
        return _main(args)
    except RuntimeError as exc:
        print(f"bench_plant: error: {exc}", file=sys.stderr)
        return 1
    except KeyboardInterrupt:
        print("bench_plant: interrupted", file=sys.stderr)
        return 130


def _main(args) -> int:
    name = f"{args.loops}x{args.days:g}d-{args.sample_time:g}s"
    plant_dir = Path(args.plant_dir or REPO / "out" / "bench_plant" / f"plant-{name}").resolve()
    work = Path(args.work_dir or REPO / "out" / "bench_plant" / f"run-{name}").resolve()
    loop_days = args.loops * args.days
    nominal = int(round(loop_days * 86400 / args.sample_time)) * 3
    cores = os.cpu_count()
    print(f"bench_plant: {args.loops} loops x {args.days:g} d at {args.sample_time:g} s = "
          f"{loop_days:,.0f} loop-days, {nominal:,} nominal samples (PV, OP, SP)")
    print(f"cpu_count: {cores}; load average before: {_loadavg()}", flush=True)

    plant_dir.mkdir(parents=True, exist_ok=True)
    work.mkdir(parents=True, exist_ok=True)
    _locks = [_lock(d) for d in sorted({plant_dir, work})]  # noqa: F841 - held to the end
    half = nominal * _BYTES_PER_SAMPLE // 2       # plant or store
    need = half if (plant_dir / MARKER).exists() else 2 * half
    free = shutil.disk_usage(work).free
    if free < need:
        raise RuntimeError(f"{work}: {free / 1e9:.1f} GB free, the benchmark needs about "
                           f"{need / 1e9:.1f} GB (plant and store); free space or use "
                           f"--work-dir/--plant-dir elsewhere")
    plant = _ensure_plant(plant_dir, args.loops, args.days, args.sample_time, args.seed)
    exports, loops_csv = plant_dir / "exports", plant_dir / "loops.csv"

    # ---- end to end: fresh store, the whole flow
    db = work / "plant.duckdb"
    _fresh_store(db)
    shutil.rmtree(work / "prefect-home", ignore_errors=True)
    mode = (f"Dask, {args.workers} workers" if args.workers
            else f"{cores} worker processes")
    print(f"end to end ({mode}): ingest into a fresh store + scan, timed ...", flush=True)
    e2e = _run_flow("e2e", work, exports, loops_csv, db, work / "out", args.workers)
    ev, t0, t1 = e2e["events"], e2e["t0"], e2e["t1"]
    _, i1 = _stage(ev, "ingest")
    _, a1 = _stage(ev, "analyse")
    nan = float("nan")
    total_s = t1 - t0
    ingest_s = (i1 - t0) if i1 else nan
    # from the ingest's end to the last loop analysed: registry, plan, the start of the
    # worker processes and the analyses
    analyse_s = (a1 - i1) if a1 and i1 else nan
    after_s = (t1 - a1) if a1 else nan
    summ = e2e["summary"]
    rows = summ["ingest"]["rows_inserted"]
    n = summ["loops"]
    mem = e2e["mem"]
    peak = mem.peak()
    peak_ingest, peak_scan = mem.peak(t0, i1), mem.peak(i1, t1)
    store_mb = db.stat().st_size / 1e6 if db.exists() else nan
    counts = ", ".join(f"{v} {k}" for v, k in summ["counts"].items())
    print(f"  loops {n}, loop-days {loop_days:,.0f}; samples stored {rows:,} "
          f"(nominal {nominal:,}; the rest compressed away by the synthetic historian)")
    print(f"  ingest:                     {ingest_s:7.1f} s  ({rows / ingest_s:,.0f} rows/s; "
          f"{plant.get('files', '?')} Parquet files, store {store_mb:,.0f} MB)")
    print(f"  plan + analysis:            {analyse_s:7.1f} s  ({n / analyse_s:.2f} loops/s; "
          f"{mode})")
    print(f"  rank + persist + outputs:   {after_s:7.1f} s")
    print(f"  total:                      {total_s:7.1f} s  (target {TARGET_S:.0f} s: "
          f"{_fmt_target(total_s, TARGET_S)})")
    print(f"  peak memory:                {peak:7,.0f} MB  (target {TARGET_MB:,.0f} MB: "
          f"{_fmt_target(peak, TARGET_MB)}; process tree, {mem.method}; ingest "
          f"{peak_ingest:,.0f} MB, scan {peak_scan:,.0f} MB; largest process "
          f"{e2e['maxrss_mb']:,.0f} MB)")
    print(f"  most threads at once:       {mem.peak_threads():7,d}  (process tree)")
    print(f"  verdicts: {counts}")
    print(f"  Prefect server start-up (not timed): {e2e['server_s']:.1f} s; cores {cores}",
          flush=True)
    figures = {"loops": n, "loop_days": loop_days, "nominal_samples": nominal,
               "samples": rows, "ingest_s": ingest_s, "plan_analyse_s": analyse_s,
               "after_s": after_s, "total_s": total_s,
               "peak_mb": peak, "peak_ingest_mb": peak_ingest, "peak_scan_mb": peak_scan,
               "maxrss_mb": e2e["maxrss_mb"], "peak_threads": mem.peak_threads(),
               "mode": mode, "cpu_count": cores, "counts": summ["counts"],
               "generate_s": plant.get("generate_s")}

    # ---- Dask: 1 vs 2 workers on a subset, same store
    if args.speedup_loops:
        k = _subset_loops(loops_csv, args.speedup_loops, work / "speedup-loops.csv")
        print(f"Dask speed-up: analysis of {k} loops with 1 and 2 workers "
              f"(same store, exports already ingested) ...", flush=True)
        sp = {}
        for w in (1, 2):
            r = _run_flow(f"dask{w}", work, exports, work / "speedup-loops.csv", db,
                          work / f"out-dask{w}", w)
            _, j1 = _stage(r["events"], "ingest")
            b0, b1 = _stage(r["events"], "analyse")
            sp[w] = {"stage_s": b1 - j1, "tasks_s": b1 - b0, "peak_mb": r["mem"].peak()}
        s1, s2 = sp[1], sp[2]
        print(f"  workers  stage [s]  tasks [s]  loops/s (tasks)  peak [MB]")
        for w in (1, 2):
            print(f"  {w:7d}  {sp[w]['stage_s']:9.1f}  {sp[w]['tasks_s']:9.1f}  "
                  f"{k / sp[w]['tasks_s']:15.2f}  {sp[w]['peak_mb']:9,.0f}")
        print(f"  speed-up 2 vs 1 workers: {s1['tasks_s'] / s2['tasks_s']:.2f}x on the tasks, "
              f"{s1['stage_s'] / s2['stage_s']:.2f}x on the stage (plan + partition export + "
              f"cluster start + tasks); {cores} cores")
        figures["speedup"] = {"loops": k, **{f"workers_{w}": v for w, v in sp.items()},
                              "tasks_ratio": s1["tasks_s"] / s2["tasks_s"],
                              "stage_ratio": s1["stage_s"] / s2["stage_s"]}

    if not args.keep:
        _fresh_store(db)
    print(f"load average after: {_loadavg()}")
    if args.json:
        print(json.dumps(figures, indent=1))
    return 0


if __name__ == "__main__":
    sys.exit(main())
