"""Progress displays of the commands (on stderr), built on :mod:`rich.progress`.

On a terminal each piece of work gets a rich progress bar (description, bar,
count done/total, elapsed time). When stderr is not a terminal (a log file, a
nightly job, a test capturing it) a plain line is printed at every tenth of the
work instead, e.g. ``analysing loops: 120/400 (30%) 4.2s``, so logs show the
progress in a few lines.

Use it as a context manager, which starts and stops the display::

    with progress_bar("simulating scenarios") as bar:
        reproduce_paper(progress=bar)                 # bar(done, total)

    with StageProgress({"ingest": "ingesting exports"}) as stages:
        run(progress=stages)                          # stages(stage, done, total)
"""
from __future__ import annotations

import sys
import threading
import time
from typing import Mapping

__all__ = ["StageProgress", "progress_bar"]


class StageProgress:
    """A progress display of several stages: ``progress(stage, done, total)``.

    Each stage gets its own bar (or its own plain lines), labelled by
    ``labels[stage]`` (the stage's name when it has no label), created at the
    stage's first report.

    Parameters
    ----------
    labels : mapping, optional
        Stage name -> description shown.
    enabled : bool
        ``False`` makes it silent.
    stream : file, optional
        Where it is shown; default ``sys.stderr`` (when entered).
    """

    def __init__(self, labels: Mapping[str, str] | None = None, *, enabled: bool = True,
                 stream=None):
        self.labels = dict(labels or {})
        self.enabled = enabled
        self._stream = stream
        self._lock = threading.Lock()
        self._rich = None          # rich.progress.Progress on a terminal, while entered
        self._tasks: dict[str, object] = {}     # stage -> rich task id
        self._plain: dict[str, list] = {}       # stage -> [start time, last tenth printed]

    # ------------------------------------------------------------------ display
    def __enter__(self) -> StageProgress:
        if not self.enabled:
            return self
        stream = self._stream if self._stream is not None else sys.stderr
        self._stream = stream
        if getattr(stream, "isatty", lambda: False)():
            from rich.console import Console
            from rich.progress import (BarColumn, MofNCompleteColumn, Progress, TextColumn,
                                       TimeElapsedColumn)

            self._rich = Progress(TextColumn("{task.description}"), BarColumn(),
                                  MofNCompleteColumn(), TimeElapsedColumn(),
                                  console=Console(file=stream), transient=False)
            self._rich.start()
        return self

    def __exit__(self, *exc) -> None:
        if self._rich is not None:
            self._rich.stop()
            self._rich = None
            self._tasks.clear()

    def __call__(self, stage: str, done: int, total: int, *_) -> None:
        if not self.enabled or total <= 0:
            return
        label = self.labels.get(stage, stage)
        with self._lock:
            if self._rich is not None:
                task = self._tasks.get(stage)
                if task is None:
                    task = self._tasks[stage] = self._rich.add_task(label, total=total)
                self._rich.update(task, completed=min(done, total), total=total)
            else:
                self._plain_line(stage, label, done, total)

    def _plain_line(self, stage: str, label: str, done: int, total: int) -> None:
        """One line at each tenth of the work: ``label: done/total (pct%) elapsed``."""
        state = self._plain.setdefault(stage, [time.perf_counter(), -1])
        frac = min(1.0, done / total)
        tenth = int(frac * 10)
        if tenth > state[1]:
            state[1] = tenth
            elapsed = time.perf_counter() - state[0]
            stream = self._stream if self._stream is not None else sys.stderr
            stream.write(f"{label}: {done:,}/{total:,} ({100 * frac:.0f}%) {elapsed:.1f}s\n")
            stream.flush()


class _OneBar:
    """A display of one piece of work: ``bar(done, total)`` (extra arguments ignored)."""

    def __init__(self, stages: StageProgress, label: str):
        self._stages = stages
        self._label = label

    def __enter__(self) -> _OneBar:
        self._stages.__enter__()
        return self

    def __exit__(self, *exc) -> None:
        self._stages.__exit__(*exc)

    def __call__(self, done: int, total: int, *_) -> None:
        self._stages(self._label, done, total)


def progress_bar(label: str, *, enabled: bool = True, stream=None) -> _OneBar:
    """A progress display of one piece of work, labelled ``label``; enter it with ``with``.

    The display is the callable ``bar(done, total)``; see the module's docstring.
    """
    return _OneBar(StageProgress(enabled=enabled, stream=stream), label)
