"""
Control-valve models: controller output (OP) to valve stem position (MV).

Each model is a pure function of the input sequence. Parameters may be scalars
or arrays, one value per scenario, so that thousands of valves are computed in
one call::

    >>> import numpy as np
    >>> from valvediag import valves
    >>> op = np.r_[np.linspace(0, 10, 11), np.linspace(9, 0, 10)]
    >>> valves.kano(op, S=4.0, J=2.0)            # one valve
    array([0., 0., 0., 2., 3., 4., 5., 6., 7., 8., 9., 9., 9., 9., 9., 6., 5.,
           4., 3., 2., 1.])
    >>> valves.kano(np.tile(op, (3, 1)), S=[2, 4, 6], J=[1, 2, 3])  # three
    array([[0. , 0. , 1.5, 2.5, 3.5, 4.5, 5.5, 6.5, 7.5, 8.5, 9.5, 9.5, 9.5,
            7.5, 6.5, 5.5, 4.5, 3.5, 2.5, 1.5, 0.5],
           [0. , 0. , 0. , 2. , 3. , 4. , 5. , 6. , 7. , 8. , 9. , 9. , 9. ,
            9. , 9. , 6. , 5. , 4. , 3. , 2. , 1. ],
           [0. , 0. , 0. , 0. , 2.5, 3.5, 4.5, 5.5, 6.5, 7.5, 8.5, 8.5, 8.5,
            8.5, 8.5, 8.5, 8.5, 4.5, 3.5, 2.5, 1.5]])

All inputs and outputs are in the same unit, usually percent of valve travel.
No clipping to 0-100 % is applied (some published code does that; real OP
ranges differ). The valve starts at rest at ``x0`` (default: the first input
value), centred in its dead band.

The step functions (:func:`valve_init`, :func:`valve_step`) are shared with the
closed-loop simulator in :mod:`valvediag.models.closedloop` and the workbench's
kernels, so open-loop, closed-loop and fitted valves agree exactly.

References
----------
.. [1] Kano, M., Maruta, H., Kugemoto, H., Shimizu, K. (2004). Practical model
   and detection algorithm for valve stiction. IFAC DYCOPS 7, Boston.
.. [2] Choudhury, M. A. A. S., Thornhill, N. F., Shah, S. L. (2005). Modelling
   valve stiction. Control Engineering Practice 13, 641-658.
.. [3] He, Q. P., Wang, J., Pottmann, M., Qin, S. J. (2007). A curve fitting
   method for detecting valve stiction in oscillating control loops.
   Ind. Eng. Chem. Res. 46, 4549-4560.
.. [4] Fisher-Rosemount (1999). Control Valve Handbook. (Definitions of dead
   band and backlash.)
"""
from __future__ import annotations

import numba
import numpy as np

__all__ = ["linear", "backlash", "kano", "choudhury", "he", "VALVE_MODELS", "apply_valve",
           "valve_init", "valve_step", "valve_flow"]

# Model codes used inside the compiled kernels.
LINEAR, BACKLASH, KANO, CHOUDHURY, HE = 0, 1, 2, 3, 4

#: name -> (code, parameter names). Parameters are in the unit of the OP.
VALVE_MODELS: dict[str, tuple[int, tuple[str, ...]]] = {
    "linear": (LINEAR, ()),
    "backlash": (BACKLASH, ("DB",)),
    "kano": (KANO, ("S", "J")),
    "choudhury": (CHOUDHURY, ("S", "J")),
    "he": (HE, ("fs", "fd")),
}

# Valve state, carried as a tuple (kept in registers by the compiler):
# (x position, u_prev, direction d, stuck flag, u at stick / residual force,
# cause of sticking, running extreme of the input in direction d).
# Why a Kano/Choudhury valve is stuck: after a reversal, after the input came to
# rest, or at the start of the record (centred in the band).
_CAUSE_REVERSAL, _CAUSE_REST, _CAUSE_START = 1.0, 0.0, 2.0


@numba.njit(cache=True, inline="always")
def valve_flow(x, curvature, centre):
    """Flow through a valve at position ``x`` with an installed characteristic.

    ``centre + expm1(curvature (x - centre)) / curvature`` [OP unit]: of unit
    slope at ``centre``; ``curvature`` [1/OP unit] > 0 an equal-percentage
    valve (its gain grows as it opens), < 0 a quick-opening one, 0 linear
    (the flow is the position)."""
    if curvature == 0.0:
        return x
    return centre + np.expm1(curvature * (x - centre)) / curvature


@numba.njit(cache=True, inline="always")
def valve_init(model, u0, x0):
    """State of a valve at rest at position ``x0`` with input ``u0``.

    Returns the state tuple ``(x, u_prev, d, stuck, u_stuck, cause,
    u_extreme)`` that :func:`valve_step` advances."""
    # the He model keeps its residual force in the fifth slot
    return x0, u0, 0.0, 1.0, (0.0 if model == HE else u0), _CAUSE_START, u0


@numba.njit(cache=True, inline="always")
def valve_step(model, p0, p1, band, u, x, up, d, stuck, us, cause, ue):
    """Advance one valve by one sample with input ``u``.

    Takes and returns the state tuple of :func:`valve_init`; ``x`` is the new
    position. ``p0, p1`` are the model's parameters (``DB``; ``S, J``;
    ``fs, fd``) and ``band`` the noise band of a Kano or Choudhury valve's
    actuator [OP unit]: a fall of the input against the direction of travel
    by no more than ``band`` from its running extreme is not a reversal (a
    moving valve holds at the extreme, a stuck one keeps its stick point);
    0 gives the models exactly as published. Compiled with numba; shared by
    the open-loop models, the closed-loop simulator and the workbench."""
    if model == LINEAR:
        x = u
    elif model == BACKLASH:
        half = 0.5 * p0
        if u - x > half:
            x = u - half
        elif x - u > half:
            x = u + half
    elif model == KANO or model == CHOUDHURY:
        S = p0
        J = p1
        du = u - up
        nd = 0.0
        if du > 0.0:
            nd = 1.0
        elif du < 0.0:
            nd = -1.0
        if nd == 0.0:
            # input at rest: a moving valve stops (no reversal)
            if stuck == 0.0:
                stuck = 1.0
                us = up
                cause = _CAUSE_REST
        elif d == 0.0:
            d = nd
            ue = u
        elif d * (u - ue) > 0.0:
            ue = u                  # on in the direction of travel
        elif d * (ue - u) > band:
            # reversal: the valve sticks where the input turned
            stuck = 1.0
            us = ue
            cause = _CAUSE_REVERSAL
            d = nd
            ue = u
        if stuck == 1.0:
            if d != 0.0:
                if cause == _CAUSE_START:
                    thr = 0.5 * S
                elif cause == _CAUSE_REVERSAL or model == CHOUDHURY:
                    thr = S
                else:
                    thr = J
                if d * (u - us) > thr:
                    x = u - d * 0.5 * (S - J)
                    stuck = 0.0
        else:
            x = ue - d * 0.5 * (S - J)
    elif model == HE:
        fs = p0
        fd = p1
        temp = u - up + us
        if abs(temp) > fs:
            us = fd if temp > 0.0 else -fd
            x = u - us
        else:
            us = temp
    return x, u, d, stuck, us, cause, ue


@numba.njit(cache=True, parallel=True)
def _run_open_loop(model, op, p0, p1, band, x0):
    m, n = op.shape
    out = np.empty_like(op)
    for i in numba.prange(m):
        x, up, d, stuck, us, cause, ue = valve_init(model, op[i, 0], x0[i])
        a = p0[i]
        b = p1[i]
        c = band[i]
        for k in range(n):
            x, up, d, stuck, us, cause, ue = valve_step(model, a, b, c, op[i, k], x, up, d, stuck,
                                                        us, cause, ue)
            out[i, k] = x
    return out


def apply_valve(model: str, op, x0=None, *, noise_band=0.0, **params) -> np.ndarray:
    """Apply a named valve model to one OP sequence or a batch of them.

    Parameters
    ----------
    model : {'linear', 'backlash', 'kano', 'choudhury', 'he'}
        Valve model name; see :data:`VALVE_MODELS` for its parameters.
    op : array_like, shape (n,) or (m, n)
        Controller output, one row per valve [OP unit, e.g. %].
    x0 : float or array_like of shape (m,), optional
        Initial valve position [OP unit]. Default: the first OP value.
    noise_band : float or array_like of shape (m,)
        Kano and Choudhury valves: a fall of the input against the direction
        of travel by no more than this from its running extreme is not a
        reversal [OP unit] (an actuator that does not reverse on OP noise;
        see :func:`kano`). Default 0: the models as published.
    **params : float or array_like of shape (m,)
        The model's parameters [OP unit].

    Returns
    -------
    numpy.ndarray
        Valve position, same shape as ``op`` [OP unit].
    """
    try:
        code, names = VALVE_MODELS[model]
    except KeyError:
        raise ValueError(f"unknown valve model {model!r}; choose from {sorted(VALVE_MODELS)}") from None
    unknown = set(params) - set(names)
    missing = set(names) - set(params)
    if unknown or missing:
        raise TypeError(f"valve model {model!r} takes parameters {names}; got {tuple(params)}")
    u = np.asarray(op, dtype=float)
    if u.ndim not in (1, 2) or u.shape[-1] == 0:
        raise ValueError("op must be a non-empty 1-D or 2-D array (scenarios x samples)")
    u2 = np.atleast_2d(u)
    m = u2.shape[0]
    vals = [np.broadcast_to(np.asarray(params[nm], dtype=float), (m,)) for nm in names]
    for nm, v in zip(names, vals):
        if np.any(~np.isfinite(v)) or np.any(v < 0):
            raise ValueError(f"valve parameter {nm} must be finite and >= 0")
    p0 = np.ascontiguousarray(vals[0]) if vals else np.zeros(m)
    p1 = np.ascontiguousarray(vals[1]) if len(vals) > 1 else np.zeros(m)
    band = np.ascontiguousarray(np.broadcast_to(np.asarray(noise_band, dtype=float), (m,)))
    if np.any(~np.isfinite(band)) or np.any(band < 0):
        raise ValueError("noise_band must be finite and >= 0")
    start = u2[:, 0] if x0 is None else np.broadcast_to(np.asarray(x0, dtype=float), (m,))
    out = _run_open_loop(code, np.ascontiguousarray(u2), p0, p1, band,
                         np.ascontiguousarray(start, dtype=float))
    return out[0] if u.ndim == 1 else out


def linear(op, x0=None):
    """Ideal valve: the position equals the controller output.

    Parameters
    ----------
    op : array_like, shape (n,) or (m, n)
        Controller output [%].
    x0 : ignored
        Accepted for a uniform signature.

    Returns
    -------
    numpy.ndarray
        Valve position [%], a copy of ``op``.
    """
    return apply_valve("linear", op)


def backlash(op, DB, x0=None):
    """Backlash (mechanical play) of total width ``DB``.

    The valve follows the input at a distance ``DB/2`` while the input keeps
    its direction. After a reversal it rests until the input has crossed the
    whole band ``DB``, then follows again. There is no jump.

    Parameters
    ----------
    op : array_like, shape (n,) or (m, n)
        Controller output [%].
    DB : float or array_like of shape (m,)
        Dead band width [%], ``DB >= 0``.
    x0 : float or array_like, optional
        Initial position [%]; default ``op[..., 0]`` (centred in the band).

    Returns
    -------
    numpy.ndarray
        Valve position [%].

    Notes
    -----
    Backlash is invertible: knowing ``DB``, a compensator can add ``DB/2``
    in the direction of travel (Hägglund 2007). It is nested in the Kano model
    (``J = 0``, ``S = DB``) for monotone input segments longer than ``DB``.

    References
    ----------
    .. [1] Hägglund, T. (2007). Automatic on-line estimation of backlash in
       control loops. Journal of Process Control 17, 489-499.
    """
    return apply_valve("backlash", op, x0=x0, DB=DB)


def kano(op, S, J, x0=None, noise_band=0.0):
    """Kano et al. (2004) two-parameter stiction model.

    The valve sticks when its input reverses or comes to rest (two equal
    consecutive samples). After a reversal it slips once the input has moved
    more than ``S`` from where it turned; after a rest, once it has moved more
    than ``J``. On slipping it jumps to ``u - d (S - J)/2`` (``d`` the
    direction of the input) and then follows the input at that distance.

    Parameters
    ----------
    op : array_like, shape (n,) or (m, n)
        Controller output [%].
    S : float or array_like of shape (m,)
        Dead band plus stick band [%].
    J : float or array_like of shape (m,)
        Slip jump [%].
    x0 : float or array_like, optional
        Initial position [%]; default ``op[..., 0]``. The valve starts at rest
        and first breaks away when the input has moved ``S/2`` from its first
        value (it is centred in its band).
    noise_band : float or array_like of shape (m,), optional
        Noise band of the actuator [%]: the input must fall back more than
        this from its running extreme to count as a reversal; meanwhile a
        moving valve holds at the extreme and a stuck one keeps its stick
        point. Default 0 (the model as published).

    Returns
    -------
    numpy.ndarray
        Valve position [%].

    Notes
    -----
    Pitfalls of the model on real data:

    * a held or compressed OP sample counts as a rest, so historian
      compression creates false stops (and false ``J`` jumps);
    * noise on the OP creates false reversals: the valve sticks at every
      one and needs the whole band ``S`` again, so it hardly moves. A real
      actuator (a pneumatic diaphragm behind a positioner) does not reverse
      on controller noise; ``noise_band`` a few times the OP's noise
      standard deviation keeps the reversals of the travel and drops those
      of the noise (the model as published when 0);
    * the apparent jump grows with the sample time: apply the model at the
      native sampling rate, do not resample;
    * the start of a record depends on the unknown initial state: discard data
      up to the first reversal or fit the initial state.

    ``J = 0`` gives a backlash of width ``S`` for monotone input segments
    longer than ``S``.

    References
    ----------
    .. [1] Kano, M., Maruta, H., Kugemoto, H., Shimizu, K. (2004). Practical
       model and detection algorithm for valve stiction. IFAC DYCOPS 7.
    """
    return apply_valve("kano", op, x0=x0, noise_band=noise_band, S=S, J=J)


def choudhury(op, S, J, x0=None):
    """Choudhury et al. (2005) data-driven stiction model.

    As :func:`kano`, except that a valve that came to rest without reversing
    must again overcome the full band ``S`` before it moves (Kano et al. use
    ``J`` there). The input is not clipped to 0-100 %.

    Parameters
    ----------
    op : array_like, shape (n,) or (m, n)
        Controller output [%].
    S : float or array_like of shape (m,)
        Dead band plus stick band [%].
    J : float or array_like of shape (m,)
        Slip jump [%].
    x0 : float or array_like, optional
        Initial position [%]; default ``op[..., 0]``.

    Returns
    -------
    numpy.ndarray
        Valve position [%].

    Notes
    -----
    With a slowly varying input sampled finely, every held sample restarts the
    stick band, so this model sticks much more than Kano's on held or
    compressed data.

    References
    ----------
    .. [1] Choudhury, M. A. A. S., Thornhill, N. F., Shah, S. L. (2005).
       Modelling valve stiction. Control Engineering Practice 13, 641-658.
    """
    return apply_valve("choudhury", op, x0=x0, S=S, J=J)


def he(op, fs, fd, x0=None):
    """He et al. (2007) stiction model with static and kinetic friction.

    A residual force accumulates the input changes. While its magnitude stays
    within the static friction ``fs`` the valve does not move; once it exceeds
    ``fs`` the valve moves and the residual drops to the kinetic friction
    ``fd`` (with the sign of travel).

    Parameters
    ----------
    op : array_like, shape (n,) or (m, n)
        Controller output [%].
    fs : float or array_like of shape (m,)
        Static friction band [%], ``fs >= fd``.
    fd : float or array_like of shape (m,)
        Kinetic friction band [%].
    x0 : float or array_like, optional
        Initial position [%]; default ``op[..., 0]``.

    Returns
    -------
    numpy.ndarray
        Valve position [%].

    Notes
    -----
    For reversals it behaves as Kano's model with ``S = fs + fd`` and
    ``J = fs - fd``; it needs no rest detection, so held samples do not create
    false stops.

    References
    ----------
    .. [1] He, Q. P., Wang, J., Pottmann, M., Qin, S. J. (2007). A curve
       fitting method for detecting valve stiction in oscillating control
       loops. Ind. Eng. Chem. Res. 46, 4549-4560.
    """
    return apply_valve("he", op, x0=x0, fs=fs, fd=fd)
