"""Valve models against hand-computed trajectories."""
import numpy as np
import pytest

from valvediag.models import valves

UP = np.arange(0.0, 11.0)            # 0, 1, ..., 10
DOWN = np.arange(9.0, -1.0, -1.0)    # 9, 8, ..., 0
UPDOWN = np.r_[UP, DOWN]


def test_linear_is_identity():
    u = np.sin(np.arange(50) * 0.3)
    np.testing.assert_array_equal(valves.linear(u), u)


def test_backlash_width():
    # starts centred: moves once the input is DB/2 = 2 away, then lags by 2;
    # after the reversal at 10 it rests until the input has crossed DB = 4.
    x = valves.backlash(UPDOWN, DB=4.0)
    expected = [0, 0, 0, 1, 2, 3, 4, 5, 6, 7, 8,      # up: u - 2 once u > 2
                8, 8, 8, 8, 7, 6, 5, 4, 3, 2]         # down: rests until u < 8 - 2 = 6
    np.testing.assert_array_equal(x, expected)


def test_kano_stick_slip_and_reversal():
    # S = 4, J = 2: first break-away at S/2 from the start with x = u - (S-J)/2;
    # after the reversal at u = 10 (x = 9) the valve sticks until u < 10 - S = 6,
    # then slips to u + (S-J)/2.
    x = valves.kano(UPDOWN, S=4.0, J=2.0)
    expected = [0, 0, 0, 2, 3, 4, 5, 6, 7, 8, 9,
                9, 9, 9, 9, 6, 5, 4, 3, 2, 1]
    np.testing.assert_array_equal(x, expected)
    # at the slip the valve jumps 9 -> 6: the slip jump J = 2 plus the one-sample
    # overshoot of the input (5 instead of 6): the apparent jump grows with the step
    assert x[14] - x[15] == pytest.approx(3.0)


def test_kano_jump_equals_J_with_fine_input():
    u = np.r_[np.arange(0, 10.001, 0.01), np.arange(9.99, 0, -0.01)]
    x = valves.kano(u, S=3.0, J=1.0)
    k = np.argmax(u)
    dx = np.diff(x[k:])
    assert dx.min() == pytest.approx(-1.0, abs=0.011)     # one jump of J
    assert np.sum(dx < -0.5) == 1


def test_kano_rest_then_same_direction_slips_after_J():
    # ramp to 5, rest for 3 samples, continue: after a rest the valve needs J, not S
    u = np.r_[np.arange(0.0, 6.0), [5.0, 5.0, 5.0], np.arange(6.0, 10.0)]
    x = valves.kano(u, S=4.0, J=2.5)
    # moving: x = u - 0.75 once started (break-away at u > 2)
    assert x[5] == pytest.approx(4.25)
    # rest at 5: stuck at 4.25; continues to 6 (1 < J), 7 (2 < J), then slips at 8 (3 > J)
    np.testing.assert_allclose(x[6:12], [4.25, 4.25, 4.25, 4.25, 4.25, 7.25])


def test_choudhury_needs_S_after_a_rest():
    u = np.r_[np.arange(0.0, 6.0), [5.0, 5.0, 5.0], np.arange(6.0, 12.0)]
    xk = valves.kano(u, S=4.0, J=2.5)
    xc = valves.choudhury(u, S=4.0, J=2.5)
    # Kano slips 3 past the rest point, Choudhury only after more than S = 4
    assert np.flatnonzero(np.diff(xk[8:]) > 0)[0] < np.flatnonzero(np.diff(xc[8:]) > 0)[0]
    assert xc[8 + 4] == pytest.approx(4.25)      # u = 9: 4 past the rest, not yet > S
    assert xc[8 + 5] == pytest.approx(10 - 0.75)


def test_kano_with_J_zero_is_backlash_of_width_S():
    t = np.arange(4000)
    u = 10 * np.sin(2 * np.pi * t / 400)
    xk = valves.kano(u, S=3.0, J=0.0)
    xb = valves.backlash(u, DB=3.0)
    np.testing.assert_allclose(xk[400:], xb[400:], atol=1e-12)


def test_he_matches_kano_on_reversals():
    # He et al. with fs = (S+J)/2, fd = (S-J)/2 moves like Kano on monotone
    # segments that are sampled more coarsely than J
    u = np.r_[np.arange(0.0, 30.0, 3.0), np.arange(27.0, 0.0, -3.0)]
    S, J = 4.0, 2.0
    xh = valves.he(u, fs=(S + J) / 2, fd=(S - J) / 2)
    xk = valves.kano(u, S=S, J=J)
    # after the first break-away both follow u - 1 going up and u + 1 coming down
    np.testing.assert_allclose(xh[3:10], u[3:10] - 1.0)
    np.testing.assert_allclose(xk[3:10], u[3:10] - 1.0)
    assert xh[-1] == pytest.approx(u[-1] + 1.0) and xk[-1] == pytest.approx(u[-1] + 1.0)


def test_vectorised_over_scenarios_equals_one_by_one():
    rng = np.random.default_rng(1)
    u = np.cumsum(rng.normal(size=(5, 300)), axis=1)
    S = np.array([0.5, 1.0, 2.0, 3.0, 4.0])
    J = S * np.array([0.5, 1.0, 0.2, 0.0, 0.7])
    both = valves.kano(u, S=S, J=J)
    for i in range(5):
        np.testing.assert_array_equal(both[i], valves.kano(u[i], S=S[i], J=J[i]))


def test_no_clipping_to_0_100():
    u = np.linspace(-50, 250, 31)
    assert valves.kano(u, S=1.0, J=0.5).max() > 200
    assert valves.backlash(u, DB=1.0).min() < -40


@pytest.mark.parametrize("kwargs", [dict(S=-1.0, J=0.0), dict(S=np.nan, J=1.0)])
def test_bad_parameters(kwargs):
    with pytest.raises(ValueError, match="must be finite and >= 0"):
        valves.kano(UP, **kwargs)


def test_unknown_model_and_parameters():
    with pytest.raises(ValueError, match="unknown valve model"):
        valves.apply_valve("sticky", UP)
    with pytest.raises(TypeError, match="takes parameters"):
        valves.apply_valve("backlash", UP, S=1.0)
