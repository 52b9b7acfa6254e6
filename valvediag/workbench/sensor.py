"""
The PV's measurement: a quantised reading (a staircase).

A transmitter of coarse resolution, an analyser that reports in fixed
steps, or a historian that stores integers records the PV on a grid
``offset + step * k``. What it records is then not the process value plus
noise but the grid point nearest to it::

    reading = offset + step * round((y + n - offset) / step)

with ``n`` the noise ahead of the quantiser (the sensor's own). A model of
``y`` alone leaves the staircase in its residual: an error of up to half a
step that follows where ``y`` lies within its grid cell. The expected
reading given ``y`` (:func:`quantised_mean`) is the best prediction in the
least-squares sense; it is a staircase rounded by the noise, and the plain
``y`` once the noise spans a step (the noise then dithers the quantiser).

Where it helps and where it cannot: with noise of a tenth of a step the
expected reading removes most of the staircase's error; with noise of a
third of a step or more the staircase is already dithered away and the
plain prediction is as good (a few per cent at most between them).
"""
from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from scipy.optimize import minimize_scalar
from scipy.special import ndtr

__all__ = ["PVGrid", "pv_grid", "quantised_mean", "fit_quantiser"]

#: A PV is on a grid when its distinct values are at most this share of its
#: samples (most readings repeat an earlier one) [-].
MAX_DISTINCT_SHARE = 0.5
#: ... and every distinct value lies within this fraction of a step of the
#: grid [-] (values read back from a text file are rounded in their last digits).
GRID_TOLERANCE = 0.02
#: Noise ahead of the quantiser searched, in steps [-]: from a hard staircase
#: (0) to a fully dithered one (1: the expected reading is then the input to
#: within 3e-9 of a step).
SPREAD_GRID = (0.0, 0.03, 0.06, 0.1, 0.15, 0.2, 0.25, 0.3, 0.4, 0.5, 0.7, 1.0)


@dataclass(frozen=True)
class PVGrid:
    """The grid a quantised PV's readings lie on.

    Attributes
    ----------
    step : float
        Quantisation step [PV unit]; 0 when the readings are not on a grid.
    offset : float
        A grid point [PV unit] (NaN when there is no grid).
    levels : int
        Distinct values read.
    samples : int
        Readings examined.
    """

    step: float
    offset: float
    levels: int
    samples: int

    @property
    def found(self) -> bool:
        """Whether the readings lie on a grid."""
        return self.step > 0

    def describe(self) -> str:
        """One sentence for a report."""
        if not self.found:
            return (f"the PV is not on a grid ({self.levels} distinct values in "
                    f"{self.samples} readings)")
        return (f"the PV reads {self.levels} values on a grid of step {self.step:.4g} "
                f"({self.samples} readings)")


def pv_grid(pv, scored=None) -> PVGrid:
    """Find the grid of a quantised PV from its readings.

    Parameters
    ----------
    pv : array_like
        Readings [PV unit]; NaN are ignored.
    scored : array_like of bool, optional
        Readings to use (for instance only the samples a historian stored:
        values interpolated between them are off any grid).

    Returns
    -------
    PVGrid
        ``step`` 0 when the readings are not on a grid.

    Notes
    -----
    The step is the smallest difference between two distinct values,
    refined by least squares over every distinct value's grid index. A
    record is on a grid only when most readings repeat an earlier value
    (:data:`MAX_DISTINCT_SHARE`) and every distinct value lies on the grid
    (:data:`GRID_TOLERANCE` of a step). A continuous PV written with a few
    decimals is on a grid too, but of a step far below its noise: its
    expected reading is the PV itself, and the effect then changes nothing.
    A PV with a few isolated readings off the grid (a spike, a substituted
    value) is taken as not quantised.
    """
    x = np.asarray(pv, dtype=float).ravel()
    if scored is not None:
        x = x[np.asarray(scored, dtype=bool).ravel()]
    x = x[np.isfinite(x)]
    u = np.unique(x)
    none = PVGrid(0.0, math.nan, int(u.size), int(x.size))
    if u.size < 3 or u.size > MAX_DISTINCT_SHARE * x.size:
        return none
    d = np.diff(u)
    q0 = float(d.min())
    if not q0 > 0:
        return none
    k = np.round((u - u[0]) / q0)
    if np.abs((u - u[0]) / q0 - k).max() > GRID_TOLERANCE:
        return none
    # least-squares line through (index, value): the step and a grid point
    kc = k - k.mean()
    step = float(kc @ (u - u.mean()) / (kc @ kc)) if kc @ kc > 0 else q0
    offset = float(u.mean() - step * k.mean())
    return PVGrid(step, offset, int(u.size), int(x.size))


def quantised_mean(y, step: float, offset: float, spread: float) -> np.ndarray:
    """Expected reading of a quantiser fed ``y`` plus Gaussian noise.

    Parameters
    ----------
    y : array_like
        Input [PV unit]; NaN stay NaN.
    step : float
        Quantisation step [PV unit]; 0 or less returns ``y``.
    offset : float
        A grid point [PV unit].
    spread : float
        Standard deviation of the noise ahead of the quantiser [PV unit]; 0
        gives the hard staircase ``offset + step round((y - offset)/step)``.

    Returns
    -------
    numpy.ndarray
        ``E[offset + step round((y + n - offset) / step)]``, ``n ~ N(0, spread^2)``.

    Notes
    -----
    With ``k`` the cell of ``y`` and ``b_m = offset + (m + 1/2) step`` the
    upper edge of cell ``m``, the reading is ``offset + step (k + #{edges
    above the cell crossed upwards} - #{edges below crossed downwards})``,
    whose expectation sums normal probabilities over the edges within six
    spreads. Beyond a spread of one step the result equals ``y`` to within
    ``step exp(-2 pi^2)``, about 3e-9 steps, and ``y`` is returned.
    """
    y = np.asarray(y, dtype=float)
    if not step > 0 or spread >= step:
        return y.copy()
    w = (y - offset) / step
    k = np.round(w)
    if spread <= 0:
        return offset + step * k
    s = spread / step
    J = int(math.ceil(6.0 * s)) + 1
    frac = w - k                                   # in [-1/2, 1/2]
    acc = k.copy()
    for j in range(J + 1):
        acc += ndtr((frac - (j + 0.5)) / s)        # edge above: k + j + 1/2
    for j in range(1, J + 1):
        acc -= ndtr((-(j - 0.5) - frac) / s)       # edge below: k - j + 1/2
    return offset + step * acc


def fit_quantiser(pv, pv_model, train, grid: PVGrid):
    """The noise ahead of the quantiser that best explains the readings.

    Parameters
    ----------
    pv : numpy.ndarray
        Readings [PV unit].
    pv_model : numpy.ndarray
        A model's prediction of the process value ahead of the quantiser
        [PV unit] (NaN where it does not predict).
    train : numpy.ndarray of bool
        Samples the spread is fitted on.
    grid : PVGrid
        From :func:`pv_grid`.

    Returns
    -------
    spread : float
        Standard deviation of the noise ahead of the quantiser [PV unit];
        ``grid.step`` or more means the staircase is dithered away.
    reading : numpy.ndarray
        :func:`quantised_mean` of ``pv_model`` at that spread.

    Notes
    -----
    The spread is searched on :data:`SPREAD_GRID` (in steps) and refined
    between the grid's neighbours of the best point by bounded scalar
    minimisation of the training squared error. The model's other
    parameters are those fitted to the readings by least squares: the
    staircase's error has mean zero over a cell, so they are not biased by
    it, only noisier.
    """
    if not grid.found:
        return math.inf, np.asarray(pv_model, dtype=float).copy()
    ok = np.asarray(train, dtype=bool) & np.isfinite(pv_model) & np.isfinite(pv)
    y, m = pv[ok], pv_model[ok]
    q, o = grid.step, grid.offset

    def sse(s):
        r = y - quantised_mean(m, q, o, s * q)
        return float(r @ r)

    vals = [sse(s) for s in SPREAD_GRID]
    i = int(np.argmin(vals))
    lo = SPREAD_GRID[max(i - 1, 0)]
    hi = SPREAD_GRID[min(i + 1, len(SPREAD_GRID) - 1)]
    best, fbest = SPREAD_GRID[i], vals[i]
    if hi > lo:
        r = minimize_scalar(sse, bounds=(lo, hi), method="bounded",
                            options={"xatol": 0.005})
        if r.fun < fbest:
            best = float(r.x)
    spread = best * q
    return spread, quantised_mean(pv_model, q, o, spread)
