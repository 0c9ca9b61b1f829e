"""Lf h + Lg h u must equal the finite-difference dh/dt along f + g u, for every model.

h is evaluated exactly as the filter does (silhouette, cone, projection
plane), at x +- dt (f + g u) with the obstacles moved by +- dt c_dot, so the
check covers the cone geometry, the barrier and each model's reference-point
kinematics together.  Samples on the documented singular set (a switch of
silhouette vertex, of the closer vertex, or of the projection plane between
the two evaluation points; the robot inside an obstacle) are discarded.
"""
import numpy as np
import pytest
from hypothesis import assume, given, HealthCheck, settings, strategies as st

from polyc2bf_ros.core.models import make_model, MODEL_NAMES
from polyc2bf_ros.core.obstacles.obstacle_set import Obstacle, ObstacleSet
from polyc2bf_ros.core.safety_filter import FilterConfig, SafetyFilter
from strategies import convex_polygons, examples, random_state

BARRIERS = {'polyc2bf_paper': {}, 'polyc2bf_inflated': {}, 'c3bf': {},
            'horizon_midpoint': {'barrier': 'polyc2bf_horizon', 'horizon': 0.8,
                                 'cone_axis': 'midpoint'},
            'horizon_bisector': {'barrier': 'polyc2bf_horizon', 'horizon': 0.8,
                                 'cone_axis': 'bisector'}}
STEP = 1e-6
RELATIVE_TOLERANCE = 1e-5


def _structure(evaluation, bisector):
    """Return what must not jump between the two evaluation points.

    k - p is constant for a fixed vertex pair of a midpoint cone; the bisector cone's k is
    the closer silhouette ray, so k + viewpoint is that vertex.
    """
    cones = evaluation.cones
    fixed = cones.k + evaluation.block[:2] if bisector else cones.k - cones.p
    return fixed, evaluation.plane, evaluation.inside


@pytest.mark.parametrize('barrier', BARRIERS)
@pytest.mark.parametrize('model_name', MODEL_NAMES)
@settings(max_examples=examples(60), deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(polygon=convex_polygons(centre_range=5.0), seed=st.integers(0, 2 ** 32 - 1),
       moving=st.booleans(), bounded=st.booleans())
def test_lie_derivatives_match_finite_differences(model_name, barrier, polygon, seed,
                                                   moving, bounded):
    """Lf h + Lg h u equals (h(x+) - h(x-)) / (2 dt) within 1e-5 relative error."""
    rng = np.random.default_rng(seed)
    model = make_model(model_name)
    config = BARRIERS[barrier] or {'barrier': barrier}
    filt = SafetyFilter(model, FilterConfig(robot_radius=0.25, **config))
    bisector = config.get('cone_axis') == 'bisector'
    z_min, z_max = (rng.uniform(-2.0, 0.0), rng.uniform(0.2, 2.0)) if bounded else (-np.inf,
                                                                                   np.inf)
    velocity = rng.uniform(-1.0, 1.0, 3) if moving else np.zeros(3)
    obstacles = ObstacleSet.from_obstacles(
        [Obstacle(polygon=polygon, velocity=velocity, z_min=z_min, z_max=z_max)])
    x = random_state(model_name, rng)
    u = rng.uniform(model.input_lower, model.input_upper)
    x_dot = model.state_derivative(x, u)

    here = filt.evaluate(x, obstacles)
    ahead = filt.evaluate(x + STEP * x_dot, obstacles, STEP)
    behind = filt.evaluate(x - STEP * x_dot, obstacles, -STEP)
    assume(not here.inside.any())
    for a, b in zip(_structure(ahead, bisector), _structure(behind, bisector)):
        assume(np.allclose(a, b, atol=1e-4))
    assume(np.allclose(_structure(here, bisector)[0], _structure(ahead, bisector)[0], atol=1e-4))

    finite_difference = (ahead.terms.h - behind.terms.h) / (2 * STEP)
    analytic = here.terms.lf_h + u @ here.terms.lg_h
    scale = np.maximum(1.0, np.abs(analytic))
    assert np.all(np.abs(finite_difference - analytic) <= RELATIVE_TOLERANCE * scale), (
        finite_difference, analytic)


def test_unicycle_steering_column_needs_offset():
    """With l = 0 the steering column of Lg h vanishes (why the paper offsets the point)."""
    obstacles = ObstacleSet.from_obstacles(
        [Obstacle(polygon=np.array([[2.0, -1.0], [3.0, -1.0], [3.0, 1.0], [2.0, 1.0]]))])
    state = np.array([0.0, 0.0, 0.3, 1.0, 0.2])
    for offset, expect_zero in ((0.0, True), (0.2, False)):
        filt = SafetyFilter(make_model('unicycle', offset_l=offset), FilterConfig())
        steering = filt.evaluate(state, obstacles).terms.lg_h[1, 0]
        assert (abs(steering) < 1e-12) == expect_zero


def test_low_wide_wall_uses_vertical_plane_and_derivatives_hold():
    """A drone before a low 10 m wall sees it in the vertical plane (smaller ||k||)."""
    wall = Obstacle(polygon=np.array([[2.0, -5.0], [2.2, -5.0], [2.2, 5.0], [2.0, 5.0]]),
                    z_min=0.0, z_max=0.5)
    obstacles = ObstacleSet.from_obstacles([wall])
    for model_name in ('point_mass_3d', 'quadrotor'):
        model = make_model(model_name)
        filt = SafetyFilter(model, FilterConfig(robot_radius=0.1))
        x = random_state(model_name, np.random.default_rng(3))
        x[:3] = [0.0, 0.3, 0.4]
        here = filt.evaluate(x, obstacles)
        assert here.plane[0] == 1
        u = (model.input_lower + model.input_upper) / 2
        x_dot = model.state_derivative(x, u)
        ahead = filt.evaluate(x + STEP * x_dot, obstacles).terms.h
        behind = filt.evaluate(x - STEP * x_dot, obstacles).terms.h
        analytic = here.terms.lf_h + u @ here.terms.lg_h
        assert np.allclose((ahead - behind) / (2 * STEP), analytic, rtol=RELATIVE_TOLERANCE,
                           atol=RELATIVE_TOLERANCE)
