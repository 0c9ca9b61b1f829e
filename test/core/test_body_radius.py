"""robot_radius is the body's: the guarded point keeps radius + offset, the body radius."""
import numpy as np
import pytest
from hypothesis import given, settings, strategies as st

from polyc2bf_ros.core.models import make_model
from polyc2bf_ros.core.obstacles.obstacle_set import Obstacle, ObstacleSet
from polyc2bf_ros.core.safety_filter import FilterConfig, SafetyFilter
from sim_bridge.rollout import clearance
from strategies import convex_polygons, examples, random_state


@pytest.mark.parametrize('model_name', ['unicycle', 'quadrotor'])
@settings(max_examples=examples(200), deadline=None)
@given(polygon=convex_polygons(centre_range=2.0), seed=st.integers(0, 2 ** 32 - 1),
       offset=st.floats(0.0, 0.5), radius=st.floats(0.05, 0.5))
def test_body_is_clear_wherever_the_guarded_point_has_its_cone(model_name, polygon, seed,
                                                               offset, radius):
    """Wherever the guarded point has its cone, the body does not touch the obstacle.

    Outside the region without a cone (the guarded point's grown obstacle), the body's
    disc (sphere) of robot_radius about its centre is clear.
    """
    rng = np.random.default_rng(seed)
    model = make_model(model_name, offset_l=offset)
    filt = SafetyFilter(model, FilterConfig(robot_radius=radius))
    assert filt.guard_radius == pytest.approx(radius + offset)
    obstacles = ObstacleSet.from_obstacles([Obstacle(polygon=polygon, z_min=-5.0, z_max=5.0)])
    state = random_state(model_name, rng)
    state[:2] = rng.uniform(-3.0, 3.0, 2)
    evaluation = filt.evaluate(state, obstacles)
    if not evaluation.inside.any():
        assert clearance(model, state, obstacles, radius) >= -1e-9


def test_clearance_measures_the_body_not_the_guarded_point():
    """A unicycle facing a wall: the clearance is from the axle, offset_l behind the point."""
    model = make_model('unicycle', offset_l=0.2)
    wall = ObstacleSet.from_obstacles([Obstacle(polygon=np.array(
        [[1.0, -1.0], [1.2, -1.0], [1.2, 1.0], [1.0, 1.0]]))])
    assert clearance(model, np.zeros(5), wall, 0.3) == pytest.approx(0.7)


def test_clearance_to_a_prism_is_euclidean_at_its_edges():
    """Beside and above a slab's front top edge: the distance to the edge, not to its face."""
    model = make_model('point_mass_3d')
    slab = ObstacleSet.from_obstacles([Obstacle(polygon=np.array(
        [[2.5, -3.0], [3.5, -3.0], [3.5, 3.0], [2.5, 3.0]]), z_min=1.4, z_max=1.6)])
    beside_above = np.array([2.482, 0.0, 1.70, 0.0, 0.0, 0.0])
    assert clearance(model, beside_above, slab, 0.1) == pytest.approx(np.hypot(0.018, 0.1) - 0.1)
    over = np.array([3.0, 0.0, 1.75, 0.0, 0.0, 0.0])
    assert clearance(model, over, slab, 0.1) == pytest.approx(0.05)
    inside = np.array([3.0, 0.0, 1.5, 0.0, 0.0, 0.0])
    assert clearance(model, inside, slab, 0.1) == pytest.approx(-0.2)
