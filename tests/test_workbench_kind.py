"""Sticky or loose valve behind a lag: the loop model's reading (valvediag.workbench.kind)."""
import datetime as dt

import numpy as np
import polars as pl
import pytest

from valvediag import classify_loop, simulate_loop
from valvediag.analysis.bi import backlash_index
from valvediag.io.registry import LoopSpec
from valvediag.scan import LoopJob, ScanConfig, analyse_loop
from valvediag.workbench.kind import ValveKind, valve_kind
from valvediag.workbench.size import NO_JUMP
from valvediag.workbench.suggest import RIVAL_T

T0 = dt.datetime(2026, 1, 1, tzinfo=dt.timezone.utc)


def level_loop(valve, params, lag, seed, kc=2.0, ti=450.0):
    """A level (integrator of 300 s) under PI control (Kc 2, Ti 450 s unless
    given) with a first-order lag between valve and PV, 3 h at 1 s after an
    hour's start-up, PV noise 1 % of its swing."""
    sim = simulate_loop(process="integrating", tau=300.0, kc=kc, ti=ti, lag=lag,
                        sample_time=1.0, duration=4 * 3600, valve=valve, valve_params=params,
                        sp_step=1.0, sp_step_time=60.0, noise_std=0.0, seed=seed)
    rng = np.random.default_rng(seed)
    pv = sim.pv + 0.01 * np.ptp(sim.pv[3600:]) * rng.standard_normal(sim.pv.size)
    return pv[3600:], sim.op[3600:]


@pytest.mark.parametrize("params,lag", [({"S": 4.0, "J": 4.0}, 20.0), ({"S": 4.0, "J": 2.0}, 20.0),
                                        ({"S": 4.0, "J": 2.0}, 40.0)])
def test_a_sticky_valve_behind_a_lag_is_read_as_sticky(params, lag):
    """The Backlash Index reads these rounded turns as a dead band; the model
    with the lag fitted finds the slip: better on the held-out segments by
    more than RIVAL_T standard errors, J at least NO_JUMP of S, S near 4."""
    pv, op = level_loop("kano", params, lag, seed=1)
    assert backlash_index(pv, 1.0).verdict == "backlash"
    k = valve_kind(pv[::2], op[::2], 2.0)
    assert k.kind == "stiction", k.reason
    assert k.t >= RIVAL_T and k.J >= NO_JUMP * k.S
    assert abs(k.S - 4.0) < 0.5, k.S
    assert "the valve slips" in k.reason
    assert k.as_dict()["kind"] == "stiction" and k.as_dict()["segments"] == k.segments


@pytest.mark.parametrize("lag,seed", [(20.0, 1), (20.0, 2), (40.0, 1), (40.0, 2)])
def test_a_loose_valve_behind_a_lag_stays_loose(lag, seed):
    """A dead band of 4 behind the same lags: the sticky valve fitted to it
    finds no slip jump worth the name or no real held-out gain."""
    pv, op = level_loop("backlash", {"DB": 4.0}, lag, seed)
    k = valve_kind(pv[::2], op[::2], 2.0)
    assert k.kind == "backlash", k.reason
    assert abs(k.DB - 4.0) < 0.4, k.DB
    assert "a dead band explains the record as well" in k.reason


def test_a_record_the_workbench_refuses_gives_an_empty_kind_and_the_reason():
    k = valve_kind(np.zeros(100), np.zeros(100), 1.0)
    assert isinstance(k, ValveKind) and k.kind == "" and "too short" in k.reason
    assert k.stiction_fit is None
    import matplotlib

    matplotlib.use("Agg")
    assert k.plot() is not None


def _frame(x):
    n = x.size
    return pl.DataFrame({"ts": pl.Series([T0 + dt.timedelta(seconds=i) for i in range(n)],
                                         dtype=pl.Datetime("us", "UTC")),
                         "value": pl.Series(x, dtype=pl.Float64),
                         "status": pl.Series([None] * n, dtype=pl.String)})


@pytest.mark.parametrize("valve,params,tuning,want",
                         [("kano", {"S": 4.0, "J": 4.0}, (1.0, 300.0), "stiction"),
                          ("backlash", {"DB": 4.0}, (2.0, 450.0), "backlash")])
def test_the_scan_checks_a_lagged_backlash_reading_with_the_model(valve, params, tuning, want):
    """Both records' turns read as a dead band, and as a sharp turn behind
    a lag once one is fitted, and the turns' timing names nothing (the
    sticky valve's controller, Kc 1 and Ti 300 s, reverses only once the
    turn is done): the scan asks the loop model. The sticky valve is called
    stiction with both methods named and its size from the fit with the lag;
    the loose valve stays backlash, with the check in its evidence."""
    pv, op = level_loop(valve, params, 20.0, seed=1, kc=tuning[0], ti=tuning[1])
    d = classify_loop(pv, op, sample_time=1.0, process_type="integrating")
    assert d.verdict == "backlash" and d.evidence["lagged_turns"]["sharp_behind_lag"]
    assert d.evidence["turn_timing"]["kind"] == ""
    spec = LoopSpec("LIC9", "LIC9.PV", "LIC9.OP", process_type="integrating", span=100.0)
    job = LoopJob(spec, T0, T0 + dt.timedelta(seconds=pv.size), ())
    r = analyse_loop(job, {"pv": _frame(pv), "op": _frame(op)}, ScanConfig(window_hours=24))
    assert r.verdict == want, r.reason
    assert r.evidence["valve_kind"]["kind"] == want
    if want == "stiction":
        assert r.evidence["valve_kind"]["lags_agree"]
        assert "Backlash Index with the lag fitted" in r.reason
        assert "loop model" in r.reason
        assert abs(r.size["S"] - 4.0) < 0.5 and r.size["J"] >= NO_JUMP * r.size["S"]
        assert "lag" in r.size["model"]
    else:
        assert "DB" in r.size


def test_lags_agree_within_the_factor_and_not_beyond():
    from valvediag.scan.loop import LAG_AGREEMENT, lags_agree

    assert lags_agree(20.0, 20.0) and lags_agree(20.0 * LAG_AGREEMENT, 20.0)
    assert lags_agree(20.0 / LAG_AGREEMENT, 20.0)
    assert not lags_agree(0.34 * 42.5, 42.5) and not lags_agree(31.0, 20.0)
    assert not lags_agree(0.0, 20.0) and not lags_agree(20.0, float("nan"))


def test_lags_within_a_sample_of_each_other_agree():
    """Two sub-sample lags read at 5 s (3.2 s at the turns, 5.0 s with the
    sticky valve: a ratio beyond the factor) cannot be told apart; a
    difference larger than the sample, or a lag that is not a number, still
    disagrees."""
    from valvediag.scan.loop import LAG_AGREEMENT, lags_agree

    assert 5.0 / 3.2 > LAG_AGREEMENT and not lags_agree(5.0, 3.2)
    assert lags_agree(5.0, 3.2, resolution=5.0) and lags_agree(0.0, 3.2, resolution=5.0)
    assert not lags_agree(31.0, 20.0, resolution=5.0)
    assert not lags_agree(float("nan"), 3.2, resolution=5.0)


def test_the_scan_names_a_slip_behind_a_lag_by_the_turns_timing():
    """A sticky valve (S 4, J 4) behind a 20 s lag: the Backlash Index reads a
    dead band, but the level turns after the OP's reversals, which the scan
    names stiction from PV and OP alone, with the method and a size."""
    pv, op = level_loop("kano", {"S": 4.0, "J": 4.0}, 20.0, seed=1)
    assert backlash_index(pv, 1.0).verdict == "backlash"
    spec = LoopSpec("LIC9", "LIC9.PV", "LIC9.OP", process_type="integrating", span=100.0)
    job = LoopJob(spec, T0, T0 + dt.timedelta(seconds=pv.size), ())
    r = analyse_loop(job, {"pv": _frame(pv), "op": _frame(op)}, ScanConfig(window_hours=24))
    assert r.verdict == "stiction", r.reason
    assert r.evidence["turn_timing"]["kind"] == "stiction"
    assert "turns' timing against the OP's reversals" in r.reason
    assert r.size is not None and np.isfinite(r.size["S"])
