"""
Closed-loop simulation: discrete PI controller -> valve -> process.

Many scenarios are simulated together; every parameter may be a scalar or an
array with one value per scenario. The process is discretised exactly under a
zero-order hold (including a fractional dead time), so the only approximation
is the sampled controller itself, as in a real DCS.

The loop, at every sample ``k`` (sample time ``h``)::

    pv_k  = y(k h) + noise_k                       measured PV
    e_k   = sp_k - pv_k
    I_k   = I_{k-1} + (h / ti) e_k                 integral state
    op_k  = kc (e_k + I_k), clipped to op_limits    (anti-windup by clamping I)
    mv_k  = valve(op_k), clipped to valve_limits   valve position
    f_k   = char(mv_k)                             flow through the valve
    v(t)  = f_k - load_k, held over [k h, (k+1) h) and delayed by dead_time
    y     <- process driven by v

Processes (``K`` = ``process_gain``, ``tau`` in seconds):

* ``'integrating'``: ``K / (tau s)``, optionally in series with a lag
  ``1 / (lag s + 1)`` and a dead time;
* ``'self-regulating'``: ``K / (tau s + 1)``, with the same options.

The loop starts in steady state at ``sp``; a set-point step, load
disturbances and measurement noise then excite it.
"""
from __future__ import annotations

from dataclasses import dataclass, field

import numba
import numpy as np
from scipy.linalg import expm

from .valves import VALVE_MODELS, valve_flow, valve_init, valve_step

__all__ = ["simulate_loop", "LoopSimulation", "process_matrices"]

# Columns of the per-scenario parameter table handed to the kernel.
(C_KC, C_TI, C_H, C_VCODE, C_VP0, C_VP1, C_ND, C_SP0, C_SPSTEP, C_SPT, C_LOAD0,
 C_LSTEP, C_LSTEPT, C_LDRIFT, C_LSINA, C_LSINW, C_LSINPHI, C_NOISE, C_SEED,
 C_OPLO, C_OPHI, C_X0, C_Y0, C_Z0, C_NMAX, C_LNOISE, C_VBAND, C_VLO, C_VHI,
 C_CURV) = range(30)
N_COLS = 30


def process_matrices(process, process_gain, tau, lag, dead_time, sample_time):
    """Exact zero-order-hold discretisation of the process, per scenario.

    Parameters
    ----------
    process : {'integrating', 'self-regulating'}
        Process type.
    process_gain, tau, lag, dead_time, sample_time : array_like, shape (m,)
        Gain [PV unit per OP unit], time constant or integration time [s], lag
        [s] (0: none), dead time [s] and sample time [s].

    Returns
    -------
    phi_f, gam_f, phi_g, gam_g : numpy.ndarray
        Transition matrices (m, 2, 2) and input vectors (m, 2) over the first
        fraction ``f h`` of a sample, during which the input is the older held
        value, and over the remaining ``(1 - f) h``.
    n_delay : numpy.ndarray of int, shape (m,)
        Whole samples of dead time; ``dead_time = (n_delay + f) h``.

    Notes
    -----
    State ``s = [z, y]``: ``z`` is the lag output (unused without a lag) and
    ``y`` the process output. The matrices come from the exponential of the
    augmented matrix ``[[A, B], [0, 0]]``, which is exact for a held input.
    """
    K, tau, lag, theta, h = np.broadcast_arrays(*(np.asarray(a, dtype=float) for a in
                                                  (process_gain, tau, lag, dead_time, sample_time)))
    m = K.shape[0]
    A = np.zeros((m, 3, 3))
    has_lag = lag > 0
    safe_lag = np.where(has_lag, lag, 1.0)
    # lag state z' = (v - z)/lag ; without a lag z is a dummy decaying state
    A[:, 0, 0] = np.where(has_lag, -1.0 / safe_lag, -1.0)
    A[:, 0, 2] = np.where(has_lag, 1.0 / safe_lag, 0.0)
    if process == "integrating":
        A[:, 1, 0] = np.where(has_lag, K / tau, 0.0)
        A[:, 1, 2] = np.where(has_lag, 0.0, K / tau)
    elif process == "self-regulating":
        A[:, 1, 1] = -1.0 / tau
        A[:, 1, 0] = np.where(has_lag, K / tau, 0.0)
        A[:, 1, 2] = np.where(has_lag, 0.0, K / tau)
    else:
        raise ValueError(f"process must be 'integrating' or 'self-regulating', not {process!r}")
    steps = theta / h
    n_delay = np.floor(steps + 1e-9).astype(np.int64)
    frac = np.clip(steps - n_delay, 0.0, 1.0)
    frac[frac < 1e-9] = 0.0
    Ef = expm(A * (frac * h)[:, None, None])
    Eg = expm(A * ((1.0 - frac) * h)[:, None, None])
    return (np.ascontiguousarray(Ef[:, :2, :2]), np.ascontiguousarray(Ef[:, :2, 2]),
            np.ascontiguousarray(Eg[:, :2, :2]), np.ascontiguousarray(Eg[:, :2, 2]), n_delay)


@numba.njit(cache=True)
def simulate_one(P, phi_f, gam_f, phi_g, gam_g, n, out_pv, out_op, out_mv, out_sp,
                 stop_reversals, rev_idx, pv_only=False, ext_load=None, ext_sp=None):
    """Simulate one loop for up to ``n`` samples into the output buffers.

    If ``stop_reversals > 0`` the run stops once the valve has reversed its
    direction of travel that many times; the sample index of each reversal is
    written to ``rev_idx``. With ``pv_only`` only ``out_pv`` is written.
    ``ext_load`` and ``ext_sp`` (length ``n``, or None) are added to the load
    and the set point at every sample. Returns the number of samples written.
    """
    kc = P[C_KC]
    h = P[C_H]
    ki = h / P[C_TI]
    vcode = int(P[C_VCODE])
    vp0 = P[C_VP0]
    vp1 = P[C_VP1]
    nd = int(P[C_ND])
    noise = P[C_NOISE]
    lnoise = P[C_LNOISE]
    if noise > 0.0 or lnoise > 0.0:
        np.random.seed(int(P[C_SEED]))
    op_lo = P[C_OPLO]
    op_hi = P[C_OPHI]
    v_lo = P[C_VLO]
    v_hi = P[C_VHI]
    curv = P[C_CURV]
    # delay line: the previous nd + 1 plant inputs v_{k-nd-1} .. v_{k-1}
    L = nd + 1
    buf = np.empty(L)
    x0 = P[C_X0]
    v0 = x0 - P[C_LOAD0]
    for j in range(L):
        buf[j] = v0
    z = P[C_Z0]
    y = P[C_Y0]
    vband = P[C_VBAND]
    vx, vup, vd, vstuck, vus, vcause, vue = valve_init(vcode, x0, x0)
    integ = x0 / kc if kc != 0.0 else 0.0
    last_dir = 0.0
    x_prev = x0
    nrev = 0
    # loop constants as scalars (the hot loop reads no parameter table)
    sp0 = P[C_SP0]
    sp1 = sp0 + P[C_SPSTEP]
    k_sp = int(np.ceil(P[C_SPT] / h - 1e-9)) if P[C_SPT] > 0 else 0
    load0 = P[C_LOAD0]
    lstep = P[C_LSTEP]
    k_ls = int(np.ceil(P[C_LSTEPT] / h - 1e-9)) if P[C_LSTEPT] > 0 else 0
    ldrift = P[C_LDRIFT]
    sin_a = P[C_LSINA]
    sin_w = P[C_LSINW]
    sin_p = P[C_LSINPHI]
    has_sin = sin_a != 0.0
    # one test per step for everything that is usually absent
    has_ext_load = ext_load is not None
    has_ext_sp = ext_sp is not None
    dynamic = has_sin or ldrift != 0.0 or lnoise > 0.0 or noise > 0.0 or \
        (lstep != 0.0 and k_ls > 0) or has_ext_load
    clipped = op_hi < np.inf or op_lo > -np.inf
    if lstep != 0.0 and k_ls == 0:
        load0 += lstep
    f00, f01, f10, f11 = phi_f[0, 0], phi_f[0, 1], phi_f[1, 0], phi_f[1, 1]
    gf0, gf1 = gam_f[0], gam_f[1]
    g00, g01, g10, g11 = phi_g[0, 0], phi_g[0, 1], phi_g[1, 0], phi_g[1, 1]
    gg0, gg1 = gam_g[0], gam_g[1]
    bi = 0  # ring-buffer position of the oldest input, v_{k-nd-1}
    # without dead time the first sub-interval is empty (identity): skip it
    direct = nd == 0 and gf0 == 0.0 and gf1 == 0.0 and f00 == 1.0 and f11 == 1.0 \
        and f01 == 0.0 and f10 == 0.0
    for k in range(n):
        sp = sp1 if k >= k_sp else sp0
        if has_ext_sp:
            sp += ext_sp[k]
        load = load0
        pv = y
        if dynamic:
            if has_ext_load:
                load += ext_load[k]
            if ldrift != 0.0:
                load += ldrift * (k * h)
            if has_sin:
                load += sin_a * np.sin(sin_w * (k * h) + sin_p)
            if k_ls > 0 and k >= k_ls:
                load += lstep
            if lnoise > 0.0:
                load += lnoise * np.random.standard_normal()
            if noise > 0.0:
                pv += noise * np.random.standard_normal()
        e = sp - pv
        integ += ki * e
        u = kc * (e + integ)
        if clipped:
            if u > op_hi:
                u = op_hi
                integ = u / kc - e
            elif u < op_lo:
                u = op_lo
                integ = u / kc - e
        vx, vup, vd, vstuck, vus, vcause, vue = valve_step(vcode, vp0, vp1, vband, u, vx, vup, vd,
                                                           vstuck, vus, vcause, vue)
        x = vx
        if x > v_hi:
            x = v_hi
        elif x < v_lo:
            x = v_lo
        out_pv[k] = pv
        if not pv_only:
            out_op[k] = u
            out_mv[k] = x
            out_sp[k] = sp
        if stop_reversals > 0:
            dx = x - x_prev
            if dx != 0.0:
                dnew = 1.0 if dx > 0.0 else -1.0
                if last_dir != 0.0 and dnew != last_dir:
                    rev_idx[nrev] = k
                    nrev += 1
                last_dir = dnew
            x_prev = x
            if nrev >= stop_reversals:
                return k + 1
        # plant input held over this sample: v_{k-nd-1} for the first
        # fraction of it, v_{k-nd} for the rest (exact fractional dead time)
        # the installed characteristic: the flow through the valve, of unit
        # slope at the starting position (the operating point)
        v_now = valve_flow(x, curv, x0) - load
        if direct:
            v_new = v_now
            z1 = z
            y1 = y
        else:
            v_old = buf[bi]
            v_new = v_now if nd == 0 else buf[bi + 1 if bi + 1 < L else 0]
            buf[bi] = v_now
            bi = bi + 1 if bi + 1 < L else 0
            z1 = f00 * z + f01 * y + gf0 * v_old
            y1 = f10 * z + f11 * y + gf1 * v_old
        z = g00 * z1 + g01 * y1 + gg0 * v_new
        y = g10 * z1 + g11 * y1 + gg1 * v_new
    return n


@numba.njit(cache=True, parallel=True)
def _simulate_batch(P, phi_f, gam_f, phi_g, gam_g, n, pv, op, mv, sp):
    m = P.shape[0]
    dummy = np.empty(1, dtype=np.int64)
    for i in numba.prange(m):
        simulate_one(P[i], phi_f[i], gam_f[i], phi_g[i], gam_g[i], n,
                     pv[i], op[i], mv[i], sp[i], 0, dummy)


@numba.njit(cache=True, parallel=True)
def _simulate_batch_profiles(P, phi_f, gam_f, phi_g, gam_g, n, pv, op, mv, sp, loads, sps):
    m = P.shape[0]
    dummy = np.empty(1, dtype=np.int64)
    for i in numba.prange(m):
        simulate_one(P[i], phi_f[i], gam_f[i], phi_g[i], gam_g[i], n,
                     pv[i], op[i], mv[i], sp[i], 0, dummy, False, loads[i], sps[i])


def parameter_table(m, *, kc, ti, sample_time, valve, valve_params, process, process_gain, tau,
                    lag, dead_time, sp, sp_step, sp_step_time, load, load_step, load_step_time,
                    load_drift, load_sin_amplitude, load_sin_period, load_sin_phase, noise_std,
                    seed, op_limits, load_noise_std=0.0, valve_noise_band=0.0,
                    valve_limits=(-np.inf, np.inf), valve_curvature=0.0):
    """Build the (m, N_COLS) kernel table and process matrices."""
    P = np.zeros((m, N_COLS))

    def col(c, v):
        P[:, c] = np.broadcast_to(np.asarray(v, dtype=float), (m,))

    col(C_KC, kc)
    col(C_TI, ti)
    col(C_H, sample_time)
    if np.any(P[:, C_KC] == 0) or np.any(~np.isfinite(P[:, C_KC])):
        raise ValueError("kc must be finite and non-zero")
    if np.any(P[:, C_TI] <= 0) or np.any(P[:, C_H] <= 0):
        raise ValueError("ti and sample_time must be > 0 [s]")
    valve_names = np.broadcast_to(np.asarray(valve, dtype=object), (m,))
    vp = dict(valve_params or {})
    vcodes = np.empty(m)
    vp0 = np.zeros(m)
    vp1 = np.zeros(m)
    for name in set(valve_names.tolist()):
        if name not in VALVE_MODELS:
            raise ValueError(f"unknown valve model {name!r}; choose from {sorted(VALVE_MODELS)}")
        code, pnames = VALVE_MODELS[name]
        sel = valve_names == name
        vcodes[sel] = code
        for slot, pn in zip((vp0, vp1), pnames):
            if pn not in vp:
                raise TypeError(f"valve model {name!r} needs valve_params[{pn!r}]")
            slot[sel] = np.broadcast_to(np.asarray(vp[pn], dtype=float), (m,))[sel]
    P[:, C_VCODE], P[:, C_VP0], P[:, C_VP1] = vcodes, vp0, vp1
    phi_f, gam_f, phi_g, gam_g, nd = process_matrices(
        process, np.broadcast_to(process_gain, (m,)), np.broadcast_to(tau, (m,)),
        np.broadcast_to(lag, (m,)), np.broadcast_to(dead_time, (m,)), P[:, C_H])
    P[:, C_ND] = nd
    col(C_SP0, sp)
    col(C_SPSTEP, sp_step)
    col(C_SPT, sp_step_time)
    col(C_LOAD0, load)
    col(C_LSTEP, load_step)
    col(C_LSTEPT, load_step_time)
    col(C_LDRIFT, load_drift)
    col(C_LSINA, load_sin_amplitude)
    per = np.broadcast_to(np.asarray(load_sin_period, dtype=float), (m,))
    P[:, C_LSINW] = np.where(np.isfinite(per) & (per > 0), 2 * np.pi / np.where(per > 0, per, 1), 0.0)
    col(C_LSINPHI, load_sin_phase)
    col(C_NOISE, noise_std)
    col(C_LNOISE, load_noise_std)
    col(C_VBAND, valve_noise_band)
    if np.any(~np.isfinite(P[:, C_VBAND])) or np.any(P[:, C_VBAND] < 0):
        raise ValueError("valve_noise_band must be finite and >= 0")
    seeds = np.random.SeedSequence(seed).generate_state(m, dtype=np.uint32) if seed is not None \
        else np.random.SeedSequence().generate_state(m, dtype=np.uint32)
    P[:, C_SEED] = seeds
    col(C_OPLO, op_limits[0])
    col(C_OPHI, op_limits[1])
    col(C_VLO, valve_limits[0])
    col(C_VHI, valve_limits[1])
    col(C_CURV, valve_curvature)
    if np.any(~np.isfinite(P[:, C_CURV])):
        raise ValueError("valve_curvature must be finite")
    # steady state at sp: the valve balances the load (integrating) or holds sp/K
    K = np.broadcast_to(np.asarray(process_gain, dtype=float), (m,))
    v0 = np.zeros(m) if process == "integrating" else P[:, C_SP0] / K
    P[:, C_X0] = v0 + P[:, C_LOAD0]
    P[:, C_Y0] = P[:, C_SP0]
    P[:, C_Z0] = v0
    return P, phi_f, gam_f, phi_g, gam_g


@dataclass(frozen=True)
class LoopSimulation:
    """Result of :func:`simulate_loop`.

    Attributes
    ----------
    t : numpy.ndarray, shape (n,)
        Sample times [s].
    pv, op, mv, sp : numpy.ndarray, shape (m, n) or (n,)
        Measured process variable, controller output, valve position and
        set point, one row per scenario.
    sample_time : numpy.ndarray, shape (m,)
        Sample time of each scenario [s].
    params : dict
        The arguments of the call, for the record.
    """

    t: np.ndarray
    pv: np.ndarray
    op: np.ndarray
    mv: np.ndarray
    sp: np.ndarray
    sample_time: np.ndarray
    params: dict = field(repr=False)

    def plot(self, ax=None, scenario: int = 0):
        """Plot PV, SP, OP and valve position of one scenario.

        Parameters
        ----------
        ax : matplotlib.axes.Axes, optional
            Axes for the PV; the OP and MV go on a twin axis.
        scenario : int
            Row to plot when the result holds several scenarios.

        Returns
        -------
        matplotlib.axes.Axes
        """
        import matplotlib.pyplot as plt

        if ax is None:
            _, ax = plt.subplots(figsize=(9, 3.5))
        row = (lambda a: a[scenario]) if self.pv.ndim == 2 else (lambda a: a)
        ax.plot(self.t, row(self.pv), color="C0", lw=1, label="PV")
        ax.plot(self.t, row(self.sp), color="k", lw=0.8, ls="--", label="SP")
        ax.set_xlabel("time [s]")
        ax.set_ylabel("PV")
        ax2 = ax.twinx()
        ax2.plot(self.t, row(self.op), color="C1", lw=0.8, label="OP")
        ax2.plot(self.t, row(self.mv), color="C2", lw=0.8, label="valve position")
        ax2.set_ylabel("OP, valve position [%]")
        lines = ax.get_lines() + ax2.get_lines()
        ax.legend(lines, [ln.get_label() for ln in lines], loc="upper right", fontsize=8)
        return ax


def simulate_loop(*, kc, ti, sample_time, duration=None, n_samples=None,
                  valve="linear", valve_params=None,
                  process="integrating", process_gain=1.0, tau=1.0, lag=0.0, dead_time=0.0,
                  sp=0.0, sp_step=0.0, sp_step_time=0.0,
                  load=0.0, load_step=0.0, load_step_time=0.0, load_drift=0.0,
                  load_sin_amplitude=0.0, load_sin_period=np.inf, load_sin_phase=0.0,
                  load_noise_std=0.0, noise_std=0.0, seed=None,
                  op_limits=(-np.inf, np.inf), valve_noise_band=0.0, load_profile=None,
                  sp_profile=None, valve_limits=(-np.inf, np.inf),
                  valve_curvature=0.0) -> LoopSimulation:
    """Simulate PI control loops with a valve model, vectorised over scenarios.

    Every numeric argument may be a scalar or an array of shape (m,), one value
    per scenario; ``valve`` may be one name or an array of names.

    Parameters
    ----------
    kc : float or array_like
        Controller gain [OP unit per PV unit]. Use a negative gain for a
        process with negative gain.
    ti : float or array_like
        Integral time [s].
    sample_time : float or array_like
        Controller and recording sample time [s].
    duration : float, optional
        Simulated time [s] (uses the largest sample time if they differ).
    n_samples : int, optional
        Number of samples instead of ``duration``.
    valve : str or array_like of str
        Valve model name, see :data:`valvediag.models.valves.VALVE_MODELS`.
    valve_params : dict, optional
        Valve parameters by name, e.g. ``{'S': 3, 'J': 1.5}`` [OP unit].
    process : {'integrating', 'self-regulating'}
        ``K/(tau s)`` or ``K/(tau s + 1)``.
    process_gain : float or array_like
        ``K`` [PV unit per OP unit].
    tau : float or array_like
        Integration time or time constant [s].
    lag : float or array_like
        Extra first-order lag in series [s]; 0 for none.
    dead_time : float or array_like
        Dead time [s]; fractional multiples of the sample time are exact.
    sp, sp_step, sp_step_time : float or array_like
        Initial set point [PV unit], a step in it and its time [s].
    load, load_step, load_step_time : float or array_like
        Load at the process input [OP unit], a step and its time [s]. For an
        integrating process the valve must match the load to hold the level.
    load_drift : float or array_like
        Load ramp rate [OP unit / s].
    load_sin_amplitude, load_sin_period, load_sin_phase : float or array_like
        Sinusoidal load [OP unit], period [s] and phase [rad].
    load_noise_std : float or array_like
        Standard deviation of a white load held over each sample [OP unit]:
        unmeasured disturbances that keep a loop moving.
    noise_std : float or array_like
        Standard deviation of white measurement noise on the PV [PV unit]; the
        controller sees the noisy PV.
    seed : int, optional
        Seed for the noise; each scenario gets its own stream.
    op_limits : tuple of float
        Controller output limits [OP unit]; the integral is clamped there.
    valve_limits : tuple of float
        Travel limits of the valve [OP unit]: its position is clipped there
        while the OP may go beyond (a valve that cannot open or close fully,
        or a positioner's stroke limit: the model workbench's
        ``saturation``). The OP limits, by contrast, leave no trace in the
        relation between the recorded OP and the PV.
    valve_curvature : float or array_like
        Installed valve characteristic [1/OP unit]: the flow through the
        valve is ``x0 + expm1(c (x - x0)) / c`` at position ``x``, of unit
        slope at the starting position ``x0``; ``c > 0`` an equal-percentage
        valve (its gain grows as it opens: ``c = ln R / 100`` for a
        rangeability R over 0-100 %), ``c < 0`` a quick-opening one. 0
        (default): linear.
    valve_noise_band : float or array_like
        Noise band of a Kano or Choudhury valve's actuator [OP unit]: the OP
        must fall back more than this from its running extreme to reverse
        the valve (:func:`valvediag.models.valves.kano`). With measurement noise fed
        back, a valve without one sticks at every noise reversal. Default 0.
    load_profile, sp_profile : array_like, shape (n,) or (m, n), optional
        Any load [OP unit] or set-point [PV unit] history, added sample by
        sample to the load and the set point above (a square wave, a random
        walk, set-point moves). Their length sets the number of samples
        when neither ``duration`` nor ``n_samples`` is given.

    Returns
    -------
    LoopSimulation

    Notes
    -----
    The dead time delays the plant input (valve position minus load). The
    controller is a positional PI with backward-rectangle integration, as
    common in DCS function blocks. Numerical cost is linear in scenarios x
    samples; the kernel runs in parallel over scenarios.

    Examples
    --------
    >>> sim = simulate_loop(kc=2, ti=50, sample_time=0.1, duration=600,
    ...                     valve='kano', valve_params={'S': 3, 'J': 1.5},
    ...                     tau=50, sp_step=1)
    """
    args = {k: v for k, v in locals().items()}
    profiles = {}
    for name in ("load_profile", "sp_profile"):
        v = args.pop(name)
        if v is not None:
            v = np.asarray(v, dtype=float)
            if v.ndim not in (1, 2) or not np.all(np.isfinite(v)):
                raise ValueError(f"{name} must be a finite array of shape (n,) or (m, n)")
            profiles[name] = v
    sizes = [np.size(v) for k, v in args.items()
             if k not in ("valve_params", "process", "seed", "op_limits", "valve_limits", "duration",
                          "n_samples")
             and not isinstance(v, str)]
    sizes += [v.shape[0] for v in profiles.values() if v.ndim == 2]
    sizes += [np.size(v) for v in (valve_params or {}).values()]
    if not isinstance(valve, str):
        sizes.append(np.size(valve))
    m = max(sizes) if sizes else 1
    P, phi_f, gam_f, phi_g, gam_g = parameter_table(
        m, kc=kc, ti=ti, sample_time=sample_time, valve=valve, valve_params=valve_params,
        process=process, process_gain=process_gain, tau=tau, lag=lag, dead_time=dead_time,
        sp=sp, sp_step=sp_step, sp_step_time=sp_step_time, load=load, load_step=load_step,
        load_step_time=load_step_time, load_drift=load_drift,
        load_sin_amplitude=load_sin_amplitude, load_sin_period=load_sin_period,
        load_sin_phase=load_sin_phase, noise_std=noise_std, seed=seed, op_limits=op_limits,
        load_noise_std=load_noise_std, valve_noise_band=valve_noise_band,
        valve_limits=valve_limits, valve_curvature=valve_curvature)
    if n_samples is None:
        if duration is not None:
            n_samples = int(np.ceil(duration / P[:, C_H].max()))
        elif profiles:
            n_samples = min(v.shape[-1] for v in profiles.values())
        else:
            raise TypeError("give duration [s] or n_samples")
    n = int(n_samples)
    if n < 1:
        raise ValueError("the simulation needs at least one sample")
    out = [np.empty((m, n)) for _ in range(4)]
    if profiles:
        ext = []
        for name in ("load_profile", "sp_profile"):
            v = profiles.get(name, np.zeros(n))
            if v.shape[-1] < n:
                raise ValueError(f"{name} has {v.shape[-1]} samples; the simulation needs {n}")
            ext.append(np.ascontiguousarray(np.broadcast_to(np.atleast_2d(v)[:, :n], (m, n))))
        _simulate_batch_profiles(P, phi_f, gam_f, phi_g, gam_g, n, *out, *ext)
    else:
        _simulate_batch(P, phi_f, gam_f, phi_g, gam_g, n, *out)
    scalar = m == 1 and all(np.ndim(v) == 0 for v in args.values() if not isinstance(v, (dict, tuple)))
    if scalar:
        out = [a[0] for a in out]
    t = np.arange(n) * P[0, C_H]
    return LoopSimulation(t=t, pv=out[0], op=out[1], mv=out[2], sp=out[3],
                          sample_time=P[:, C_H].copy(), params=args)
