"""
Figures of the maintenance report: one inline SVG per loop, drawn reproducibly.

:func:`loop_figure` draws the evidence behind one loop's verdict in one
figure (five panels) from the plot data the scan kept
(:class:`valvediag.scan.LoopDetail`):

* the PV, SP and OP over the window with the oscillating episodes shaded
  (:meth:`valvediag.scan.LoopTrend.plot`);
* a zoom on a few cycles: for a valve fault the Backlash Index evidence,
  peaks, valleys, middle points and the measured angles
  (:meth:`valvediag.analysis.bi.BacklashIndex.plot`); for a linear oscillation the
  PV and OP with the apices;
* the phase plot of the mean cycle, OP against the implied valve position
  (:meth:`valvediag.analysis.linearity.CycleShape.plot`), or, where the
  loop records its valve position and that position backs the verdict, the
  position against the OP with its jumps in red
  (:meth:`valvediag.analysis.travel.ValveTravel.plot`);
* for a valve fault, the Backlash Index of every half cycle against the
  verdict limits; for a swing that keeps a clock's time, the start of each
  cycle against the best steady clock
  (:class:`valvediag.analysis.oscillation.PhaseWander`); for another linear
  oscillation, the mean PV cycle against a pure sine wave (its harmonic
  distortion is what makes it linear).

:func:`loop_figure` writes the SVG elements itself
(:func:`valvediag.report.plot.loop_svg`): the same text, byte for byte,
for the same data, with ids under a prefix so that many figures live in one
HTML page; 5-15 ms a figure on one core, 450 figures of real plant data in
~7 s. (Drawn with matplotlib the figures took 0.5-1 s each, most of it
tick and text layout: ~95 % of a plant report's cost.)
:func:`render_loop_figures` can spread the figures over worker processes,
but starting them and pickling the results costs more than it saves below
:data:`PARALLEL_MIN` figures (450 figures on 2 cores: 7.4 s in one process,
19.5 s with two workers).
"""
from __future__ import annotations

__all__ = ["loop_figure", "render_loop_figures"]


def loop_figure(result, prefix: str, *, zoom_cycles: float = 4.0) -> str | None:
    """The evidence figure of one loop needing action, as inline SVG.

    Parameters
    ----------
    result : valvediag.scan.LoopResult
        A ranked result whose ``detail`` holds a trend and a diagnosis.
    prefix : str
        Id prefix, unique in the page.
    zoom_cycles : float
        Cycles shown in the zoom panel [-].

    Returns
    -------
    str or None
        The ``<svg>`` element; None when the result carries no plot data.

    Notes
    -----
    Drawn by :func:`valvediag.report.plot.loop_svg`, which writes the SVG
    directly (a few ms per figure).
    """
    from .plot import loop_svg

    return loop_svg(result, prefix, zoom_cycles=zoom_cycles)


#: Fewest figures for which :func:`render_loop_figures` starts worker processes.
PARALLEL_MIN = 2000


def _auto_workers(n: int) -> int:
    import os

    env = os.environ.get("VALVEDIAG_REPORT_WORKERS")
    if env:
        try:
            return max(1, int(env))
        except ValueError:
            pass
    if n < PARALLEL_MIN:
        return 1
    return max(1, min(os.cpu_count() or 1, 4, n // (PARALLEL_MIN // 2)))


def _render_chunk(jobs) -> list[str | None]:
    return [loop_figure(r, p, zoom_cycles=z) for r, p, z in jobs]


def _worker_main(argv) -> int:
    """``python -m valvediag.report.figures IN OUT``: render pickled jobs, pickle the SVGs."""
    import pickle

    with open(argv[0], "rb") as fh:
        jobs = pickle.load(fh)
    out = _render_chunk(jobs)
    with open(argv[1], "wb") as fh:
        pickle.dump(out, fh, protocol=pickle.HIGHEST_PROTOCOL)
    return 0


def render_loop_figures(jobs, *, workers: int | None = None, zoom_cycles: float = 4.0
                        ) -> list[str | None]:
    """Render many loop figures, in worker processes when there are many.

    Parameters
    ----------
    jobs : sequence of (LoopResult, str)
        Results and their id prefixes.
    workers : int, optional
        Processes; default: one below :data:`PARALLEL_MIN` figures, else up
        to ``min(os.cpu_count(), 4)`` (environment variable
        ``VALVEDIAG_REPORT_WORKERS`` overrides).
    zoom_cycles : float
        See :func:`loop_figure` [-].

    Returns
    -------
    list of str or None
        One SVG per job, in order; the same bytes whichever the number of
        workers.

    Notes
    -----
    The workers are plain subprocesses (``python -m
    valvediag.report.figures``) that get their share of the jobs as a pickle
    file: unlike :mod:`multiprocessing` they never re-import the caller's
    ``__main__``, so a script without an ``if __name__ == "__main__"`` guard,
    a notebook or a Prefect worker is safe. Each costs about a second to
    start. A worker that fails has its share drawn in this process. Workers
    run in the directory holding this package (``python -m`` puts the working
    directory first on ``sys.path``), so they import the same ``valvediag``
    as the caller whatever its working directory.
    """
    import os
    import pickle
    import subprocess
    import sys
    import tempfile
    from pathlib import Path

    jobs = [(r, p, zoom_cycles) for r, p in jobs]
    n = len(jobs)
    workers = _auto_workers(n) if workers is None else max(1, int(workers))
    if workers <= 1 or n < 2:
        return _render_chunk(jobs)
    workers = min(workers, n)
    chunks = [jobs[k::workers] for k in range(workers)]     # interleaved: similar cost
    package_root = str(Path(__file__).resolve().parents[2])
    env = dict(os.environ)
    env["PYTHONPATH"] = os.pathsep.join([package_root] + [p for p in
                                         env.get("PYTHONPATH", "").split(os.pathsep) if p])
    env.setdefault("MPLBACKEND", "Agg")
    results: list = [None] * workers
    with tempfile.TemporaryDirectory(prefix="valvediag-figures-") as tmp:
        procs = []
        for k, chunk in enumerate(chunks):
            src, dst = os.path.join(tmp, f"in{k}.pkl"), os.path.join(tmp, f"out{k}.pkl")
            with open(src, "wb") as fh:
                pickle.dump(chunk, fh, protocol=pickle.HIGHEST_PROTOCOL)
            try:
                proc = subprocess.Popen([sys.executable, "-m", "valvediag.report.figures",
                                         src, dst], env=env, cwd=package_root,
                                        stdin=subprocess.DEVNULL,
                                        stdout=subprocess.DEVNULL, stderr=subprocess.PIPE)
            except OSError:
                proc = None
            procs.append((proc, dst))
        for k, (proc, dst) in enumerate(procs):
            if proc is not None:
                _, err = proc.communicate()
                if proc.returncode == 0 and os.path.isfile(dst):
                    with open(dst, "rb") as fh:
                        results[k] = pickle.load(fh)
                    continue
            results[k] = _render_chunk(chunks[k])    # the worker failed: draw here
    out: list = [None] * n
    for k in range(workers):
        out[k::workers] = results[k]
    return out


if __name__ == "__main__":   # a worker of render_loop_figures
    import sys

    raise SystemExit(_worker_main(sys.argv[1:]))
