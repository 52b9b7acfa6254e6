"""
Planning a plant scan: every loop's analysis window, decided before any data is read.
"""
from __future__ import annotations

import datetime as dt
from collections.abc import Sequence
from typing import TYPE_CHECKING

from ..io.registry import LoopSpec

if TYPE_CHECKING:  # pragma: no cover

    from ..store.database import Store

from .types import LoopJob, ScanConfig

_UTC = dt.timezone.utc
_SECOND = dt.timedelta(seconds=1)


def plan_loops(store: Store, loops: Sequence[LoopSpec], config: ScanConfig = ScanConfig()
               ) -> list[LoopJob]:
    """Decide every loop's window and note what is missing, before reading data.

    Parameters
    ----------
    store : valvediag.store.Store
        The store holding the samples.
    loops : sequence of LoopSpec
        The registry (every loop gets a job, even one without tags).
    config : ScanConfig
        ``window_hours`` and ``end`` are used.

    Returns
    -------
    list of LoopJob
        In registry order.

    Notes
    -----
    Without ``config.end`` a loop's window ends at the first whole second
    after its latest PV sample (bad or good), else its latest OP sample, else
    the latest sample of the whole store (a loop with no data at all); the
    window ``[start, end)`` thus holds that sample. One query reads the latest
    time stamp of every tag.
    """
    latest = store.latest_timestamps()
    last = dict(zip(latest["tag"].to_list(), latest["last_ts"].to_list()))
    plant_end = max(last.values()) if last else dt.datetime.now(_UTC)
    jobs = []
    for spec in loops:
        problems = list(spec.issues)
        for role, tag in spec.tags.items():
            if tag not in last:
                problems.append(f"{role.upper()} tag {tag} not found in the exports")
        if config.end is not None:
            end = config.end
        else:
            latest_ts = (last.get(spec.pv_tag) or last.get(spec.op_tag) or plant_end)
            end = latest_ts.astimezone(_UTC).replace(microsecond=0) + _SECOND
        end = end.astimezone(_UTC)
        jobs.append(LoopJob(spec=spec, start=end - config.window, end=end,
                            problems=tuple(problems)))
    return jobs


