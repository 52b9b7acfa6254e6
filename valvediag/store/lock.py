"""
One scan at a time per store: an operating-system file lock beside the DuckDB file.

DuckDB's own lock only lasts while a process has the file open, and a scan
opens and closes the store many times (the analysis runs without it). Two
scans started together would interleave their writes. :class:`ScanLock`
closes that gap: a scan holds ``<db>.scan.lock`` (``flock``, exclusive) from
its start to its end. A second scan waits for it, at most ``timeout``
seconds, then fails with :class:`ScanLockedError`, one line naming the store
and the scan that holds it.

The operating system drops the lock when its process dies, even by
``SIGKILL``. So the scan that holds the lock knows that every run still
marked ``running`` in the store belongs to a scan that died, and marks it
``aborted`` (:meth:`valvediag.store.Store.abort_stale_runs`).

Notes
-----
``flock`` is reliable on local file systems. On network file systems (NFS)
it depends on the server; keep the store on a local disk of the machine
that runs the flow (distributed workers never open it).
"""
from __future__ import annotations

import datetime as dt
import fcntl
import json
import os
import socket
import threading
import time
from pathlib import Path

from .database import StoreLockedError

__all__ = ["ScanLock", "ScanLockedError", "lock_path", "owner_id"]

#: Locks this process holds: lock file -> [descriptor, holders]. A second
#: ScanLock of the same store in the same process (the command line holds the
#: lock around the flow, which takes it again) shares the descriptor: ``flock``
#: would refuse it a second open of the file.
_HELD: dict[Path, list] = {}
_HELD_GUARD = threading.Lock()


class ScanLockedError(StoreLockedError):
    """Another scan holds the store. The message is one line naming the store."""


def lock_path(db_path: str | os.PathLike) -> Path:
    """The lock file of a store: ``<db>.scan.lock`` beside it.

    Parameters
    ----------
    db_path : str or path-like
        The DuckDB file.
    """
    db = Path(os.fspath(db_path)).resolve()
    return db.with_name(db.name + ".scan.lock")


def owner_id() -> str:
    """``pid@host`` of this process (stored with a run so a dead owner can be named)."""
    return f"{os.getpid()}@{socket.gethostname()}"


class ScanLock:
    """Exclusive lock of a store for one scan.

    Parameters
    ----------
    db_path : str or path-like
        The DuckDB file (need not exist yet).
    timeout : float, default 0
        Longest wait for another scan to finish [s]; 0 fails at once.
    poll : float, default 0.2
        Interval between attempts while waiting [s].

    Raises
    ------
    ScanLockedError
        From :meth:`acquire` (or ``with``): still held after ``timeout``.

    Examples
    --------
    >>> with ScanLock("plant.duckdb", timeout=600):      # doctest: +SKIP
    ...     ...  # ingest, plan, analyse, persist
    """

    def __init__(self, db_path: str | os.PathLike, *, timeout: float = 0.0, poll: float = 0.2):
        self.db_path = os.fspath(db_path)
        self.path = lock_path(db_path)
        self.timeout = max(float(timeout), 0.0)
        self.poll = max(float(poll), 0.01)
        self._fd: int | None = None

    @property
    def held(self) -> bool:
        """True while this object holds the lock."""
        return self._fd is not None

    def holder(self) -> dict:
        """What the current holder wrote into the lock file (``pid, host, since``); may be {}."""
        try:
            return json.loads(self.path.read_text(encoding="utf-8") or "{}")
        except (OSError, ValueError):
            return {}

    def acquire(self) -> ScanLock:
        """Take the lock, waiting at most ``timeout`` seconds.

        Within one process the lock is reentrant: while one ScanLock of the
        store is held, another one of the same store is granted at once, and
        the file lock is given up when the last of them is released.

        Returns
        -------
        ScanLock
            ``self``.
        """
        if self._fd is not None:
            return self
        with _HELD_GUARD:
            shared = _HELD.get(self.path)
            if shared is not None:
                shared[1] += 1
                self._fd = shared[0]
                return self
        self.path.parent.mkdir(parents=True, exist_ok=True)
        fd = os.open(self.path, os.O_RDWR | os.O_CREAT, 0o644)
        deadline = time.monotonic() + self.timeout
        while True:
            try:
                fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
                break
            except BlockingIOError:
                if time.monotonic() >= deadline:
                    os.close(fd)
                    raise ScanLockedError(self._message()) from None
                time.sleep(min(self.poll, max(deadline - time.monotonic(), 0.01)))
        info = {"pid": os.getpid(), "host": socket.gethostname(),
                "since": dt.datetime.now(dt.timezone.utc).isoformat(timespec="seconds")}
        os.ftruncate(fd, 0)
        os.pwrite(fd, json.dumps(info).encode(), 0)
        with _HELD_GUARD:
            _HELD[self.path] = [fd, 1]
        self._fd = fd
        return self

    def _message(self) -> str:
        h = self.holder()
        who = (f" (pid {h.get('pid')} on {h.get('host')}, since {h.get('since')})"
               if h.get("pid") else "")
        waited = f" after waiting {self.timeout:g} s" if self.timeout else ""
        return (f"{self.db_path}: another scan is running on this store{who}; still busy"
                f"{waited}. Wait for it to finish, or give it time with --wait SECONDS")

    def release(self) -> None:
        """Give the lock up (nothing when not held)."""
        if self._fd is None:
            return
        fd, self._fd = self._fd, None
        with _HELD_GUARD:
            shared = _HELD.get(self.path)
            if shared is not None and shared[0] == fd:
                shared[1] -= 1
                if shared[1] > 0:
                    return
                del _HELD[self.path]
        try:
            os.ftruncate(fd, 0)
            fcntl.flock(fd, fcntl.LOCK_UN)
        finally:
            os.close(fd)

    def __enter__(self) -> ScanLock:
        return self.acquire()

    def __exit__(self, *exc) -> None:
        self.release()
