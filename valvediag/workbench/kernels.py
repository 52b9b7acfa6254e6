"""
Compiled kernels of the workbench: the OP-driven chain and batch scoring.

The chain, per sample ``k`` (sample time ``h``)::

    x_k   = sat(valve(op_k))                 valve position      [OP unit]
    f_k   = char(x_k)                        flow through it     [OP unit]
                                             (m + expm1(c (x - m)) / c,
                                             c = 0: linear)
    xd_k  = f_{k - D}                        delayed flow        [OP unit]
                                             (D in samples, fractional:
                                             linear interpolation)
    s_k+1 = Phi s_k + Gam xd_k               s = [z, r]: lag output and the
                                             unit-gain plant response

``Phi`` and ``Gam`` are the exact zero-order-hold matrices of the lag and the
plant (integrator or first order) with unit gain, from
:func:`valvediag.models.closedloop.process_matrices`. The valve step is the one of
:mod:`valvediag.models.valves` (shared with the closed-loop simulator).

The score of a candidate is the least-squares error of the PV prediction
over re-initialised segments. The prediction is linear in the plant gain and
in the load coefficients, so those are solved exactly (variable projection):
per segment the free response of the plant (a constant for an integrator,
``a**j`` for a first-order plant) is projected out, which re-initialises the
prediction to the best initial state of the segment.
"""
from __future__ import annotations

import numba
import numpy as np

from ..models.valves import HE, valve_flow, valve_init, valve_step

__all__ = ["simulate_chain", "score_batch", "turning_points", "nudge_holds",
           "project_free_response", "plant_load_columns"]


@numba.njit(cache=True, inline="always")
def _chain(u, vcode, p0, p1, band, us0, lo, hi, delay, f00, f01, f10, f11, g0, g1, curv, mid,
           r_out, x_out, xd_out, z_out, keep):
    n = u.shape[0]
    x, up, d, stuck, us, cause, ue = valve_init(vcode, u[0], u[0])
    if vcode == HE:
        # He's valve keeps the phase of its stick-slip steps for ever: its
        # initial residual force is a parameter (|us0| <= fs: at rest)
        us = us0
    x0 = min(max(u[0], lo), hi)
    x0 = valve_flow(x0, curv, mid)
    nd = int(np.floor(delay))
    fr = delay - nd
    # ring buffer of the last nd + 2 positions: x_{k-nd-1} .. x_k
    L = nd + 2
    buf = np.empty(L)
    for j in range(L):
        buf[j] = x0
    w = 0                  # where x_k goes
    ia = L - nd if nd > 0 else 0        # x_{k-nd}
    if ia >= L:
        ia -= L
    ib = ia - 1 if ia > 0 else L - 1    # x_{k-nd-1}
    z = x0
    r = 0.0
    for k in range(n):
        x, up, d, stuck, us, cause, ue = valve_step(vcode, p0, p1, band, u[k], x, up, d, stuck, us,
                                                    cause, ue)
        xs = min(max(x, lo), hi)
        buf[w] = valve_flow(xs, curv, mid)
        xd = (1.0 - fr) * buf[ia] + fr * buf[ib] if fr > 0.0 else buf[ia]
        w = w + 1 if w + 1 < L else 0
        ia = ia + 1 if ia + 1 < L else 0
        ib = ib + 1 if ib + 1 < L else 0
        if keep:
            x_out[k] = xs
            xd_out[k] = xd
            z_out[k] = z
        r_out[k] = r
        z1 = f00 * z + f01 * r + g0 * xd
        r = f10 * z + f11 * r + g1 * xd
        z = z1


@numba.njit(cache=True, nogil=True)
def simulate_chain(u, vcode, p0, p1, band, us0, lo, hi, delay, f00, f01, f10, f11, g0, g1, curv,
                   mid, x_out, xd_out, z_out, r_out):
    """Run the chain on one OP record, keeping every intermediate signal.

    ``delay`` is the dead time in samples (fractional: the delayed position
    interpolates linearly between samples, which is exact for the integral
    of a held input). ``r_out[k]`` is the unit-gain plant response at sample
    ``k``, driven by the delayed, lagged valve positions before ``k``."""
    _chain(u, vcode, p0, p1, band, us0, lo, hi, delay, f00, f01, f10, f11, g0, g1, curv, mid,
           r_out, x_out, xd_out, z_out, True)


@numba.njit(cache=True, inline="always")
def _chain_response(u, vcode, p0, p1, band, us0, lo, hi, delay, f00, f01, f10, f11, g0, g1,
                    curv, mid, r_out):
    """Unit-gain plant response of the chain only (the sequential part)."""
    _chain(u, vcode, p0, p1, band, us0, lo, hi, delay, f00, f01, f10, f11, g0, g1, curv, mid,
           r_out, r_out, r_out, r_out, False)


@numba.njit(cache=True, nogil=True, fastmath=True)
def _score_one(u, vcode, P, i, seg_start, seg_end, seg_set, wt, qv, WT, qW, anchored, Py, ystats,
               G2, Ginv, GinvWy, out, r):
    p = WT.shape[1]
    ns = seg_start.shape[0]
    _chain_response(u, vcode, P[i, 0], P[i, 1], P[i, 12], P[i, 11], P[i, 2], P[i, 3], P[i, 4],
                    P[i, 5], P[i, 6], P[i, 7], P[i, 8], P[i, 9], P[i, 10], P[i, 13], P[i, 14], r)
    integ = qv.shape[0] > 1 and qv[1] == 1.0
    # inner products of the projected response, per set (0 train, 1 held-out)
    rr = np.zeros(2)
    ry = np.zeros(2)
    rW = np.zeros((2, p))
    for j in range(ns):
        st = seg_set[j]
        if st < 0:
            continue
        a = seg_start[j]
        b = seg_end[j]
        s_rr = 0.0
        s_ry = 0.0
        if anchored:
            # re-initialised at the measured PV: remove the free response
            # from the segment's first value
            off = r[a]
            for k in range(a, b):
                rc = r[k] - qv[k - a] * off
                s_rr += wt[k] * rc * rc
                s_ry += rc * Py[k]
            rr[st] += s_rr
        else:
            # re-initialised at the best initial state: project the free
            # response out; for an integrator a constant per segment is
            # projected out anyway, so subtract the first value to keep the
            # sums well scaled
            off = r[a] if integ else 0.0
            sq = 0.0
            qq = 0.0
            for k in range(a, b):
                rc = r[k] - off
                q = qv[k - a] * wt[k]
                s_rr += wt[k] * rc * rc
                s_ry += rc * Py[k]
                sq += q * rc
                qq += q * q
            rr[st] += s_rr - (sq * sq / qq if qq > 0.0 else 0.0)
        ry[st] += s_ry
        # offset part of the fixed columns' inner products (zero when they
        # are projected: orthogonal to each segment's free response)
        for c in range(p):
            rW[st, c] -= off * qW[j, c]
    # inner products with the fixed columns: one contiguous dot product per
    # column and set (WT is masked per set)
    for t2 in range(2):
        for c in range(p):
            w = WT[t2, c]
            s_w = 0.0
            for k in range(r.shape[0]):
                s_w += r[k] * w[k]
            rW[t2, c] += s_w
    # training least squares, Schur complement on the gain column
    a0 = rr[0]
    cGb = 0.0
    for c in range(p):
        cGb += rW[0, c] * GinvWy[c]
    sc = a0
    for c1 in range(p):
        t = 0.0
        for c2 in range(p):
            t += Ginv[c1, c2] * rW[0, c2]
        sc -= rW[0, c1] * t
    gain = (ry[0] - cGb) / sc if (a0 > 0.0 and sc > 1e-12 * a0) else 0.0
    coef = np.empty(p)
    for c1 in range(p):
        t = 0.0
        for c2 in range(p):
            t += Ginv[c1, c2] * (ystats[0, 1 + c2] - rW[0, c2] * gain)
        coef[c1] = t
    out[i, 2] = gain
    for c in range(p):
        out[i, 3 + c] = coef[c]
    # error sum of squares per set, from the inner products
    for t2 in range(2):
        sse = ystats[t2, 0] - 2.0 * gain * ry[t2] + gain * gain * rr[t2]
        for c1 in range(p):
            sse += 2.0 * coef[c1] * (gain * rW[t2, c1] - ystats[t2, 1 + c1])
            for c2 in range(p):
                sse += coef[c1] * G2[t2, c1, c2] * coef[c2]
        out[i, t2] = sse


@numba.njit(cache=True, parallel=True)
def score_batch(u, vcode, P, seg_start, seg_end, seg_set, wt, qv, WT, qW, anchored, Py, ystats,
                G2, Ginv, GinvWy, out):
    """Score a batch of candidates in parallel (see :func:`score_serial`).

    It keeps the GIL (unlike the other kernels): numba's fallback threading
    layer (workqueue) aborts on concurrent launches from several threads.
    Threads should call :func:`score_serial`, which releases it."""
    n = u.shape[0]
    for i in numba.prange(P.shape[0]):
        r = np.empty(n)
        _score_one(u, vcode, P, i, seg_start, seg_end, seg_set, wt, qv, WT, qW, anchored, Py,
                   ystats, G2, Ginv, GinvWy, out, r)


@numba.njit(cache=True, nogil=True)
def score_serial(u, vcode, P, seg_start, seg_end, seg_set, wt, qv, WT, qW, anchored, Py, ystats,
                 G2, Ginv, GinvWy, out):
    """Score a batch of candidate chains, one after the other.

    Parameters (all float64 unless noted)
    ----------
    u : (n,) OP
    vcode : int, valve model code
    P : (m, 15) candidates: p0, p1, lo, hi, delay [samples], f00, f01, f10, f11, g0, g1,
        us0 (initial residual force of He's valve), band (noise band of a Kano valve),
        curvature and centre of the valve's characteristic
    seg_start, seg_end : (ns,) int64 segment bounds [start, end)
    seg_set : (ns,) int64, 0 training, 1 held-out, -1 unused
    wt : (n,) 1 where a sample is scored, 0 where not (a PV sample the
         historian did not store, read back by interpolation)
    qv : (Lmax,) free response of the plant from a unit initial state,
         ``qa**j`` (all ones for an integrator)
    WT : (2, p, n) projected fixed columns (load terms), per set (zero
         outside the set's segments)
    qW : (ns, p) per segment, the sum of ``qv * W`` (zero for projected
         columns)
    anchored : bool, re-initialise at the measured first PV of each segment
         (else at the best initial state: projection)
    Py : (n,) projected PV
    ystats : (2, 1 + p) per set: [yy, Wy_0..Wy_p-1]
    G2 : (2, p, p) Gram matrices of the fixed columns per set
    Ginv : (p, p) inverse Gram of the training fixed columns
    GinvWy : (p,) ``Ginv @ Wy_train``
    out : (m, 3 + p) written: sse_train, sse_heldout, gain, coef_0..p-1

    Starting a parallel region costs milliseconds on a busy machine, so
    single candidates (local refinement) use this serial version.
    """
    r = np.empty(u.shape[0])
    for i in range(P.shape[0]):
        _score_one(u, vcode, P, i, seg_start, seg_end, seg_set, wt, qv, WT, qW, anchored, Py,
                   ystats, G2, Ginv, GinvWy, out, r)


@numba.njit(cache=True, inline="always")
def _free_response(x, use, i0, i1, w, anchored, from_first):
    """One segment's free response in ``x`` at the samples ``use[i0:i1]``:
    ``x - shift - w coef`` removes it. Anchored, from the segment's first
    value (shift 0, coef that value); else projected out, after the first
    value is subtracted when ``from_first``."""
    x0 = x[use[i0]]
    if anchored:
        return 0.0, x0
    shift = x0 if from_first else 0.0
    num = 0.0
    den = 0.0
    for i in range(i0, i1):
        num += w[i] * (x[use[i]] - shift)
        den += w[i] * w[i]
    return shift, (num / den if den > 0.0 else 0.0)


@numba.njit(cache=True, nogil=True)
def project_free_response(X, use, first, w, anchored, from_first, out):
    """Remove each segment's free response from the rows of ``X``, into ``out``.

    Parameters
    ----------
    X : numpy.ndarray, shape (p, n)
        One signal per row.
    use : numpy.ndarray of int64, shape (m,)
        The scored samples, segment by segment (in time order within each).
    first : numpy.ndarray of int64
        Position in ``use`` of each segment's first scored sample.
    w : numpy.ndarray, shape (m,)
        The plant's free response at each scored sample (``a**j``; ones
        for an integrator).
    anchored : bool
        Subtract the free response from the segment's first value, else
        project it out (the best initial state).
    from_first : bool
        (Projecting) subtract the segment's first value first (an
        integrator's precision).
    out : numpy.ndarray, shape (p, n)
        Written at the scored samples.
    """
    m = use.size
    nseg = first.size
    for c in range(X.shape[0]):
        x = X[c]
        o = out[c]
        for r in range(nseg):
            i0 = first[r]
            i1 = first[r + 1] if r + 1 < nseg else m
            shift, coef = _free_response(x, use, i0, i1, w, anchored, from_first)
            for i in range(i0, i1):
                o[use[i]] = x[use[i]] - shift - w[i] * coef


@numba.njit(cache=True, nogil=True)
def plant_load_columns(B, a, g, use, first, w, sets, anchored, from_first, WT, buf):
    """Load signals through the plant, each segment's free response removed, per sample set.

    Parameters
    ----------
    B : numpy.ndarray, shape (p, n)
        The load signals, one per row, held per sample.
    a, g : float
        The plant with unit gain, ``y_k = a y_(k-1) + g b_(k-1)`` from
        ``y_0 = 0`` (``a = 1, g = h`` an integrator; ``a = exp(-h/tau),
        g = 1 - a`` a first-order plant).
    use, first, w, anchored, from_first
        As :func:`project_free_response`.
    sets : numpy.ndarray of int64, shape (n,)
        Sample set of each sample: 0 training, 1 held-out.
    WT : numpy.ndarray, shape (2, p, n)
        Written whole: row ``c`` of set ``s`` holds the projected response
        at that set's samples and zero elsewhere.
    buf : numpy.ndarray, shape (n,)
        Work space.
    """
    p, n = B.shape
    m = use.size
    nseg = first.size
    for c in range(p):
        y = 0.0
        buf[0] = 0.0
        WT[0, c, 0] = 0.0
        WT[1, c, 0] = 0.0
        for k in range(1, n):
            y = g * B[c, k - 1] + a * y
            buf[k] = y
            WT[0, c, k] = 0.0
            WT[1, c, k] = 0.0
        for r in range(nseg):
            i0 = first[r]
            i1 = first[r + 1] if r + 1 < nseg else m
            shift, coef = _free_response(buf, use, i0, i1, w, anchored, from_first)
            for i in range(i0, i1):
                k = use[i]
                WT[sets[k], c, k] = buf[k] - shift - w[i] * coef


@numba.njit(cache=True, nogil=True)
def turning_points(u, delta):
    """Reversals of ``u`` with hysteresis ``delta``.

    An extreme is confirmed once ``u`` has moved more than ``delta`` away
    from it, so noise smaller than ``delta`` makes no reversal. Returns the
    index of each extreme, its sign (+1 maximum, -1 minimum) and the index at
    which it was confirmed."""
    n = u.shape[0]
    idx = np.empty(n, np.int64)
    sgn = np.empty(n, np.int64)
    conf = np.empty(n, np.int64)
    m = 0
    hi_i = 0
    lo_i = 0
    d = 0          # +1 rising (looking for a maximum), -1 falling, 0 unknown
    for k in range(1, n):
        v = u[k]
        if v != v:
            continue
        if u[hi_i] != u[hi_i] or v > u[hi_i]:
            hi_i = k
        if u[lo_i] != u[lo_i] or v < u[lo_i]:
            lo_i = k
        if d >= 0 and u[hi_i] - v > delta:
            # a maximum at hi_i, confirmed now (ignore the very first if unknown)
            idx[m] = hi_i
            sgn[m] = 1
            conf[m] = k
            m += 1
            d = -1
            lo_i = k
        elif d <= 0 and v - u[lo_i] > delta:
            idx[m] = lo_i
            sgn[m] = -1
            conf[m] = k
            m += 1
            d = 1
            hi_i = k
    return idx[:m], sgn[:m], conf[:m]


@numba.njit(cache=True, nogil=True)
def nudge_holds(u, max_run, eps):
    """OP as a Kano valve should see it when held samples are not rests.

    Within a run of at most ``max_run`` repeated samples the value creeps on
    by ``eps`` per sample in the last direction of travel, so the valve
    model finds neither a rest nor a reversal there; longer runs stay
    (genuine rests)."""
    n = u.shape[0]
    out = u.copy()
    d = 0.0
    k = 1
    while k < n:
        if u[k] != u[k - 1]:
            d = 1.0 if u[k] > u[k - 1] else -1.0
            k += 1
            continue
        j = k
        while j < n and u[j] == u[j - 1]:
            j += 1
        if j - k <= max_run and d != 0.0:
            for i in range(k, j):
                out[i] = out[i - 1] + d * eps
        k = j
    return out

