"""Constant-velocity Kalman filter (polyc2bf_ros.core.obstacles.constant_velocity).

Hand-computed steps, properties of random sequences (symmetric positive definite
covariances), and the compiled helpers against the numpy functions, which are checked here
against plain matrix formulas written out again.
"""
import math

import numpy as np
import pytest
from hypothesis import given, settings, strategies as st

from polyc2bf_ros.core.kernels import tracking
from polyc2bf_ros.core.obstacles import constant_velocity as cv
from strategies import examples

SETTINGS = settings(max_examples=examples(100), deadline=None)
RELATIVE = np.array([[1.0, 0.0, 0.0, 0.0, -1.0, 0.0], [0.0, 1.0, 0.0, 0.0, 0.0, -1.0]])


def _spd(rng, size, scale=1.0):
    """Return a random symmetric positive definite matrix."""
    factor = rng.normal(size=(size, size)) * scale
    return factor @ factor.T + 1e-3 * scale * scale * np.eye(size)


def _is_spd(matrix):
    """Return whether ``matrix`` is symmetric with positive eigenvalues."""
    return (np.array_equal(matrix, matrix.T)
            and np.linalg.eigvalsh(matrix).min() > 0.0)


def test_predict_by_hand():
    """Predict x = [1, 2, 3, 4], P = I by dt = 0.5 with accel_std = 2, by hand per axis.

    F P F^T = [[1 + dt^2, dt], [dt, 1]] = [[1.25, 0.5], [0.5, 1]]; Q = 4 [[dt^3 / 3, dt^2 /
    2], [dt^2 / 2, dt]] = [[1/6, 0.5], [0.5, 2]].
    """
    x, P = cv.predict(np.array([1.0, 2.0, 3.0, 4.0]), np.eye(4), 0.5, 2.0)
    np.testing.assert_allclose(x, [2.5, 4.0, 3.0, 4.0])
    axis = np.array([[1.25 + 1 / 6, 1.0], [1.0, 3.0]])
    expected = np.zeros((4, 4))
    expected[np.ix_([0, 2], [0, 2])] = expected[np.ix_([1, 3], [1, 3])] = axis
    np.testing.assert_allclose(P, expected, rtol=1e-12, atol=1e-12)


def test_update_by_hand():
    """One axis with P = [[2, 1], [1, 1]], R = 2, z = 4 from x = 0: S = 4, K = [1/2, 1/4].

    x' = K z = [2, 1]; P' = P - K S K^T = [[1, 0.5], [0.5, 0.75]]; the other axis, measured
    where it is predicted, keeps its state and gets the same covariance.
    """
    P = np.zeros((4, 4))
    P[np.ix_([0, 2], [0, 2])] = P[np.ix_([1, 3], [1, 3])] = [[2.0, 1.0], [1.0, 1.0]]
    x, P = cv.update(np.zeros(4), P, np.array([4.0, 0.0]), 2.0 * np.eye(2))
    np.testing.assert_allclose(x, [2.0, 0.0, 1.0, 0.0], atol=1e-12)
    axis = [[1.0, 0.5], [0.5, 0.75]]
    np.testing.assert_allclose(P[np.ix_([0, 2], [0, 2])], axis, atol=1e-12)
    np.testing.assert_allclose(P[np.ix_([1, 3], [1, 3])], axis, atol=1e-12)
    assert np.abs(P[np.ix_([0, 2], [1, 3])]).max() < 1e-12


def test_initial():
    """Position as measured, velocity 0 with ``speed_std`` per axis."""
    x, P = cv.initial(np.array([1.0, -2.0]), np.array([[0.04, 0.01], [0.01, 0.09]]), 1.5)
    np.testing.assert_array_equal(x, [1.0, -2.0, 0.0, 0.0])
    np.testing.assert_array_equal(P[:2, :2], [[0.04, 0.01], [0.01, 0.09]])
    np.testing.assert_array_equal(P[2:, 2:], 2.25 * np.eye(2))
    assert not P[:2, 2:].any()


@pytest.mark.parametrize('dt, accel_std', [(-0.1, 1.0), (math.nan, 1.0), (0.1, -1.0),
                                           (0.1, math.inf)])
def test_predict_refuses_bad_steps(dt, accel_std):
    """A negative or non-finite time step or acceleration is an error, in one line."""
    with pytest.raises(ValueError) as error:
        cv.predict(np.zeros(4), np.eye(4), dt, accel_std)
    assert '\n' not in str(error.value)


@given(seed=st.integers(0, 2 ** 32 - 1), steps=st.integers(1, 30))
@SETTINGS
def test_sequences_stay_symmetric_positive_definite(seed, steps):
    """Predictions and updates, with R from 1e-6 to 1e6 in scale, keep P symmetric and PD."""
    rng = np.random.default_rng(seed)
    x, P = cv.initial(rng.normal(size=2), _spd(rng, 2, 0.1), rng.uniform(0.1, 3.0))
    for _ in range(steps):
        x, P = cv.predict(x, P, rng.uniform(0.0, 0.3), rng.uniform(0.0, 2.0))
        assert _is_spd(P)
        R = _spd(rng, 2, 10.0 ** rng.uniform(-3, 3))
        x, P = cv.update(x, P, x[:2] + rng.normal(size=2), R)
        assert _is_spd(P)
        assert np.isfinite(x).all()


@given(seed=st.integers(0, 2 ** 32 - 1))
@SETTINGS
def test_update_matches_the_textbook_formulas(seed):
    """``update`` equals x + K y, (I - K H) P with K = P H^T (H P H^T + R)^-1, written out."""
    rng = np.random.default_rng(seed)
    x, P, R, z = rng.normal(size=4), _spd(rng, 4), _spd(rng, 2), rng.normal(size=2)
    H = np.hstack([np.eye(2), np.zeros((2, 2))])
    gain = P @ H.T @ np.linalg.inv(H @ P @ H.T + R)
    new_x, new_P = cv.update(x, P, z, R)
    np.testing.assert_allclose(new_x, x + gain @ (z - H @ x), rtol=1e-9, atol=1e-9)
    np.testing.assert_allclose(new_P, (np.eye(4) - gain @ H) @ P, rtol=1e-7, atol=1e-9)


@given(seed=st.integers(0, 2 ** 32 - 1))
@SETTINGS
def test_compiled_helpers_match_numpy(seed):
    """The compiled helpers compute what the numpy functions compute.

    ``predict_all``, ``update_rows``, and ``update_one`` then ``reclone_one`` for a relative
    measurement, with and without a free direction.
    """
    rng = np.random.default_rng(seed)
    x, P = rng.normal(size=4), _spd(rng, 4)
    dt, accel = rng.uniform(0.0, 0.3), rng.uniform(0.0, 2.0)
    states, covariances = x[None].copy(), P[None].copy()
    tracking.predict_all(states, covariances, dt, accel)
    expected_x, expected_P = cv.predict(x, P, dt, accel)
    np.testing.assert_allclose(states[0], expected_x, atol=1e-12)
    np.testing.assert_allclose(covariances[0], expected_P, rtol=1e-12, atol=1e-12)
    z, R = rng.normal(size=2), _spd(rng, 2, 10.0 ** rng.uniform(-2, 2))
    tracking.update_rows(states, covariances, np.array([0]), z[None].copy(), R[None].copy())
    expected_x, expected_P = cv.update(expected_x, expected_P, z, R)
    np.testing.assert_allclose(states[0], expected_x, rtol=1e-9, atol=1e-9)
    np.testing.assert_allclose(covariances[0], expected_P, rtol=1e-9, atol=1e-9)
    x6, P6 = cv.clone(expected_x, expected_P)
    x6, P6 = cv.predict(x6, P6, dt, accel)
    angle = rng.uniform(0, 2 * math.pi)
    free = np.array([math.cos(angle), math.sin(angle)]) if rng.random() < 0.5 else None
    d = rng.normal(size=2)
    expected_x, expected_P = cv.reclone(*cv.update_relative(x6, P6, d, R, free))
    state, covariance = x6.copy(), P6.copy()
    y = d - RELATIVE @ state
    tracking.update_one(state, covariance, RELATIVE, y[0], y[1], R[0, 0], R[0, 1], R[1, 1],
                  *((0.0, 0.0) if free is None else free), np.empty((18, 6)))
    tracking.reclone_one(state, covariance)
    np.testing.assert_allclose(state, expected_x, rtol=1e-9, atol=1e-9)
    np.testing.assert_allclose(covariance, expected_P, rtol=1e-8, atol=1e-9)


@given(seed=st.integers(0, 2 ** 32 - 1))
@SETTINGS
def test_relative_update(seed):
    """A displacement measures p - c, and a free direction w is left alone.

    A zero innovation changes nothing; the clone is p's copy; with a free direction w no
    (x, y) pair moves along w, and P stays symmetric PD.
    """
    rng = np.random.default_rng(seed)
    x6, P6 = cv.clone(rng.normal(size=4), _spd(rng, 4))
    assert x6[4] == x6[0] and x6[5] == x6[1]
    np.testing.assert_array_equal(P6[4:, :4], P6[:2, :4])
    x6, P6 = cv.predict(x6, P6, rng.uniform(0.01, 0.3), rng.uniform(0.1, 2.0))
    R = _spd(rng, 2, 0.01)
    same_x, same_P = cv.update_relative(x6, P6, x6[:2] - x6[4:], R)
    np.testing.assert_allclose(same_x, x6, atol=1e-12)
    assert _is_spd(same_P)
    angle = rng.uniform(0, 2 * math.pi)
    w = np.array([math.cos(angle), math.sin(angle)])
    moved_x, moved_P = cv.update_relative(x6, P6, rng.normal(size=2), R, free=w)
    change = (moved_x - x6).reshape(3, 2)
    np.testing.assert_allclose(change @ w, 0.0, atol=1e-12)
    assert _is_spd(moved_P)
    free_x, _ = cv.update_relative(x6, P6, x6[:2] - x6[4:] + 0.1 * w, R)
    assert np.abs((free_x - x6).reshape(3, 2) @ w).max() > 0.0  # without it, w moves


@given(seed=st.integers(0, 2 ** 32 - 1))
@SETTINGS
def test_velocity_std_is_the_worst_axis(seed):
    """``velocity_std`` is the square root of P_vv's largest eigenvalue."""
    P = _spd(np.random.default_rng(seed), 4)
    assert math.isclose(cv.velocity_std(P), math.sqrt(np.linalg.eigvalsh(P[2:, 2:]).max()),
                        rel_tol=1e-9)
