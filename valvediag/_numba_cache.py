"""Keep numba's on-disk cache consistent with the package's sources.

Numba keys a cached function on its own file only: a kernel in ``paper.py``
that calls ``bi.robust_bi_kernel`` keeps its stale machine code after
``bi.py`` changes. We therefore point numba at a cache directory named after a
hash of every module that holds compiled code, so that an edit to any of them
invalidates all kernels.
The user's own ``NUMBA_CACHE_DIR`` wins if set.
"""
from __future__ import annotations

import hashlib
import os
import sys
from pathlib import Path


def configure() -> None:
    if "NUMBA_CACHE_DIR" in os.environ or "numba" in sys.modules:
        return
    here = Path(__file__).resolve().parent
    h = hashlib.sha1()
    for f in sorted(here.rglob("*.py")):
        src = f.read_bytes()
        if b"import numba" in src:
            h.update(f.name.encode())
            h.update(src)
    base = Path(os.environ.get("XDG_CACHE_HOME", Path.home() / ".cache")) / "valvediag"
    os.environ["NUMBA_CACHE_DIR"] = str(base / f"numba-{h.hexdigest()[:12]}")
