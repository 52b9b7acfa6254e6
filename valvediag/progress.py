"""A small progress bar for long work on a terminal (stderr)."""
from __future__ import annotations

import sys
import time


class ProgressBar:
    """Callable progress display: ``bar(done, total)``.

    Draws on stderr when it is a terminal, and otherwise prints a line at
    every tenth of the work, so logs of a nightly job show progress too.

    Parameters
    ----------
    label : str
        What is being done.
    stream : file, optional
        Default ``sys.stderr``.
    enabled : bool
        ``False`` makes it silent.
    """

    def __init__(self, label: str, stream=None, enabled: bool = True):
        self.label = label
        self.stream = stream if stream is not None else sys.stderr
        self.enabled = enabled
        self.t0 = time.perf_counter()
        self._last_decile = -1
        self._tty = hasattr(self.stream, "isatty") and self.stream.isatty()

    def __call__(self, done: int, total: int, *_):
        if not self.enabled or total <= 0:
            return
        frac = min(1.0, done / total)
        el = time.perf_counter() - self.t0
        eta = el / frac - el if frac > 0 else float("nan")
        if self._tty:
            w = 30
            fill = int(round(w * frac))
            self.stream.write(f"\r{self.label} [{'#' * fill}{'.' * (w - fill)}] "
                              f"{done:,}/{total:,} {el:5.1f}s eta {eta:5.1f}s")
            if done >= total:
                self.stream.write("\n")
            self.stream.flush()
        else:
            dec = int(frac * 10)
            if dec > self._last_decile:
                self._last_decile = dec
                self.stream.write(f"{self.label}: {done:,}/{total:,} ({100 * frac:.0f}%) {el:.1f}s\n")
                self.stream.flush()
