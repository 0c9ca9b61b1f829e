"""Robust rows for accelerating obstacles: Lf h - a_o |dh/dv| on moving parts only."""
import numpy as np
import pytest
from hypothesis import given, HealthCheck, settings, strategies as st

from polyc2bf_ros.core.kernels.cones import PLANE_ROWS
from polyc2bf_ros.core.models import make_model
from polyc2bf_ros.core.obstacles.obstacle_set import Obstacle, ObstacleSet
from polyc2bf_ros.core.safety_filter import FilterConfig, SafetyFilter
from strategies import convex_polygons, examples, random_state

SETTINGS = settings(max_examples=examples(30), deadline=None,
                    suppress_health_check=[HealthCheck.too_slow])
PLANAR = ('unicycle', 'point_mass_2d')


def _evaluations(model_name, barrier, accel, state, obstacles):
    """Return the evaluation blocks of the same step without and with ``accel``."""
    model = make_model(model_name)
    blocks = []
    for a in (0.0, accel):
        filt = SafetyFilter(model, FilterConfig(barrier=barrier, obstacle_accel=a))
        blocks.append(filt.evaluate(state, obstacles).block.copy())
    return model, blocks


@SETTINGS
@given(model_name=st.sampled_from(PLANAR),
       barrier=st.sampled_from(['polyc2bf_horizon', 'polyc2bf_inflated', 'c3bf']),
       polygons=st.lists(convex_polygons(centre_range=6.0), min_size=1, max_size=6),
       seed=st.integers(0, 2**31 - 1), accel=st.floats(0.1, 3.0))
def test_only_moving_parts_are_tightened_by_accel_times_dh_dv(model_name, barrier, polygons,
                                                             seed, accel):
    """Moving parts: Lf h drops by a_o |p + (s / |v|_e) v|; h, Lg h and static parts stay."""
    rng = np.random.default_rng(seed)
    moving = rng.random(len(polygons)) < 0.5
    velocities = [rng.uniform(-1.0, 1.0, 3) if m else np.zeros(3) for m in moving]
    obstacles = ObstacleSet.from_obstacles(
        [Obstacle(polygon=p, velocity=v) for p, v in zip(polygons, velocities)])
    state = random_state(model_name, rng)
    model, (plain, robust) = _evaluations(model_name, barrier, accel, state, obstacles)
    lf = PLANE_ROWS + 1
    assert np.array_equal(np.delete(robust, lf, axis=0), np.delete(plain, lf, axis=0),
                          equal_nan=True)
    ref = model.reference(state)
    eps = FilterConfig().velocity_epsilon
    for n, v_obs in enumerate(velocities):
        v = v_obs[:2] - ref.velocity
        dh_dv = plain[2:4, n] + plain[6, n] / np.sqrt(v @ v + eps * eps) * v
        expected = plain[lf, n] - (accel * np.linalg.norm(dh_dv) if moving[n] else 0.0)
        assert robust[lf, n] == pytest.approx(expected, rel=1e-12, abs=1e-12)


def test_a_moving_obstacle_head_on_needs_braking_sooner():
    """Closing on a box that moves towards the robot: the robust row asks for more braking."""
    model = make_model('unicycle')
    box = np.array([[2.0, -0.5], [3.0, -0.5], [3.0, 0.5], [2.0, 0.5]])
    obstacles = ObstacleSet.from_obstacles([Obstacle(polygon=box, velocity=[-0.5, 0.0, 0.0])])
    state = np.array([0.0, 0.0, 0.0, 1.0, 0.0])
    nominal = np.zeros(model.input_dim)
    plain, _ = SafetyFilter(model, FilterConfig()).step(state, obstacles, nominal)
    robust, _ = SafetyFilter(model, FilterConfig(obstacle_accel=2.0)).step(
        state, obstacles, nominal)
    assert robust[0] < plain[0]


@pytest.mark.parametrize('value', [-0.1, float('nan'), float('inf')])
def test_obstacle_accel_must_be_finite_and_non_negative(value):
    """A negative or non-finite bound is refused, naming the field."""
    with pytest.raises(ValueError, match='obstacle_accel'):
        FilterConfig(obstacle_accel=value).validate()


@SETTINGS
@given(model_name=st.sampled_from(PLANAR),
       barrier=st.sampled_from(['polyc2bf_horizon', 'polyc2bf_inflated']),
       polygons=st.lists(convex_polygons(centre_range=6.0), min_size=1, max_size=4),
       seed=st.integers(0, 2**31 - 1), error=st.floats(0.05, 0.5))
def test_a_velocity_error_lowers_lf_h_by_its_worst_first_order_effect(model_name, barrier,
                                                                     polygons, seed, error):
    """Moving parts: Lf h drops by e (|dh/dp| + gamma |dh/dv|); h, Lg h and static parts stay.

    And the bound on h is true: h at any velocity within e of the estimate is at least
    h - e |dh/dv| (h is convex in v where s >= 0).
    """
    rng = np.random.default_rng(seed)
    moving = rng.random(len(polygons)) < 0.6
    velocities = [rng.uniform(-1.0, 1.0, 3) * [1, 1, 0] if m else np.zeros(3) for m in moving]
    obstacles = ObstacleSet.from_obstacles(
        [Obstacle(polygon=p, velocity=v) for p, v in zip(polygons, velocities)])
    state = random_state(model_name, rng)
    model = make_model(model_name)
    config = FilterConfig(barrier=barrier)
    plain = SafetyFilter(model, config).evaluate(state, obstacles).block.copy()
    robust = SafetyFilter(model, FilterConfig(barrier=barrier, obstacle_velocity_error=error)
                          ).evaluate(state, obstacles).block.copy()
    lf = PLANE_ROWS + 1
    assert np.array_equal(np.delete(robust, lf, axis=0), np.delete(plain, lf, axis=0),
                          equal_nan=True)
    ref = model.reference(state)
    eps = config.velocity_epsilon
    single = SafetyFilter(model, config)
    for n, v_obs in enumerate(velocities):
        v = v_obs[:2] - ref.velocity
        speed = np.sqrt(v @ v + eps * eps)
        dh_dv = np.linalg.norm(plain[2:4, n] + plain[6, n] / speed * v)
        dh_dp = np.linalg.norm(v + speed * plain[7:9, n])
        drop = error * (dh_dp + config.gamma * dh_dv) if moving[n] else 0.0
        assert robust[lf, n] == pytest.approx(plain[lf, n] - drop, rel=1e-12, abs=1e-12)
        if not moving[n] or plain[6, n] < 0.0 or not np.isfinite(plain[PLANE_ROWS, n]):
            continue
        h_plain = single.evaluate(state, ObstacleSet.from_obstacles(
            [Obstacle(polygon=polygons[n], velocity=v_obs)])).block[PLANE_ROWS, 0]
        for angle in np.linspace(0.0, 2.0 * np.pi, 8, endpoint=False):
            delta = error * np.array([np.cos(angle), np.sin(angle), 0.0])
            h_true = single.evaluate(state, ObstacleSet.from_obstacles(
                [Obstacle(polygon=polygons[n], velocity=v_obs + delta)])).block[PLANE_ROWS, 0]
            assert h_true >= h_plain - error * dh_dv - 1e-9


@pytest.mark.parametrize('value', [-0.1, float('nan'), float('inf')])
def test_obstacle_velocity_error_must_be_finite_and_non_negative(value):
    """A bad velocity error bound is refused, naming the field."""
    with pytest.raises(ValueError, match='obstacle_velocity_error'):
        FilterConfig(obstacle_velocity_error=value).validate()
