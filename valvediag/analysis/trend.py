"""
The trend behind a verdict: PV and OP against time, for the result objects' plots.
"""
from __future__ import annotations

import numpy as np

__all__ = ["pv_op_trend"]


def pv_op_trend(ax, pv, op, sample_time: float, reason: str, *, pv_width: float = 0.7):
    """Draw the PV, and the OP on a twin axis, against time.

    Parameters
    ----------
    ax : matplotlib.axes.Axes or None
        Where to draw; a new 9 x 3.5 inch figure when None.
    pv, op : numpy.ndarray or None
        The record [PV unit, OP unit]; without a PV, ``reason`` is written
        in the axes instead; without an OP, only the PV is drawn.
    sample_time : float
        [s]
    reason : str
        What the axes say when there is nothing to draw.
    pv_width : float
        Line width of the PV.

    Returns
    -------
    ax : matplotlib.axes.Axes
    t : numpy.ndarray or None
        Time of each sample [s], for the caller's marks; None when nothing
        was drawn.
    """
    import matplotlib.pyplot as plt

    if ax is None:
        _, ax = plt.subplots(figsize=(9, 3.5))
    if pv is None:
        ax.text(0.5, 0.5, reason, ha="center", va="center", transform=ax.transAxes)
        return ax, None
    t = np.arange(pv.size) * sample_time
    ax.plot(t, pv, lw=pv_width, color="C0", label="PV")
    if op is not None:
        ax2 = ax.twinx()
        ax2.plot(t, op, lw=0.6, color="C1", alpha=0.7, label="OP")
        ax2.set_ylabel("OP")
    ax.set_xlabel("time [s]")
    ax.set_ylabel("PV")
    return ax, t
