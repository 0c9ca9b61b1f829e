"""A step that starts outside the safe set is flagged ``recovering``, and h is driven back up."""
import numpy as np
import pytest

from polyc2bf_ros.core.models import make_model
from polyc2bf_ros.core.obstacles.obstacle_set import Obstacle, ObstacleSet
from polyc2bf_ros.core.safety_filter import FilterConfig, FilterStatus, SafetyFilter

BOX = np.array([[2.0, -0.5], [3.0, -0.5], [3.0, 0.5], [2.0, 0.5]])


@pytest.mark.parametrize('barrier', ['polyc2bf_inflated', 'polyc2bf_horizon'])
def test_start_inside_the_cone_is_flagged_and_recovered(barrier):
    """Heading at a box at 1 m/s: h < 0 at the start, flagged until h >= 0.

    The exact (bisector) cone's h is continuous, so it then stays >= 0; the midpoint cone's
    h jumps where a silhouette vertex switches while the robot rounds the box, and each such
    step is flagged again.
    """
    model = make_model('point_mass_2d', max_accel=3.0)
    period = 0.01
    filt = SafetyFilter(model, FilterConfig(barrier=barrier, robot_radius=0.2,
                                            control_period=period, horizon=2.0,
                                            braking_check=False))
    obstacles = ObstacleSet.from_obstacles([Obstacle(polygon=BOX)])
    state = np.array([0.0, 0.05, 1.0, 0.0])
    nominal = np.zeros(2)  # the nominal holds the velocity: only the filter turns it
    statuses, min_h = [], []
    for _ in range(300):
        u, info = filt.step(state, obstacles, nominal)
        statuses.append(info.status)
        min_h.append(info.min_h)
        state = state + period * model.state_derivative(state, u)
    assert statuses[0] == FilterStatus.RECOVERING and min_h[0] < 0
    assert 'min h' in filt.step(np.array([0.0, 0.05, 1.0, 0.0]), obstacles, nominal)[1].message
    first_safe = next(k for k, h in enumerate(min_h) if h >= 0)
    assert all(s == FilterStatus.RECOVERING for s in statuses[:first_safe])
    assert all((h < 0) == (s == FilterStatus.RECOVERING) for h, s in zip(min_h, statuses))
    if barrier == 'polyc2bf_horizon':
        assert min(min_h[first_safe:]) >= 0
