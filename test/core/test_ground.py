"""The ground as an obstacle for 3-D models: the floor slab, floor-standing prisms, rollouts."""
import math

import numpy as np
import pytest

from polyc2bf_ros.core.models import make_model
from polyc2bf_ros.core.obstacles.ground import GROUND_DEPTH, grounded
from polyc2bf_ros.core.obstacles.obstacle_set import Obstacle, ObstacleSet
from polyc2bf_ros.core.safety_filter import FilterConfig, SafetyFilter
from sim_bridge.nominal import PointMassGoalController, QuadrotorGoalController
from sim_bridge.rollout import clearance, rollout

WALL = np.array([[2.0, -2.0], [2.2, -2.0], [2.2, 2.0], [2.0, 2.0]])


def test_floor_standing_prisms_reach_down_and_the_floor_is_the_last_part():
    """z_min <= ground + R: extended to the slab's bottom; above it: kept; one slab more."""
    obstacles = ObstacleSet.from_obstacles([
        Obstacle(polygon=WALL, z_min=0.0, z_max=3.0),
        Obstacle(polygon=WALL + [2.0, 0.0], z_min=1.4, z_max=1.6)])
    ground = grounded(obstacles, 0.0, 0.1)
    assert len(ground) == 3
    assert ground.z_ranges[0, 0] == -GROUND_DEPTH and ground.z_ranges[0, 1] == 3.0
    assert ground.z_ranges[1, 0] == 1.4
    assert ground.z_ranges[2, 1] == 0.0
    assert grounded(obstacles, 0.0, 0.1) is ground  # cached in the set


def test_no_ground_by_default_and_infinite_disables():
    """ground_z = -inf (the default) adds nothing; a finite one adds the floor's row."""
    obstacles = ObstacleSet.from_obstacles([Obstacle(polygon=WALL, z_min=0.0, z_max=3.0)])
    state = np.zeros(6)
    state[2] = 1.0
    model = make_model('point_mass_3d')
    assert FilterConfig().ground_z == -math.inf
    _, info = SafetyFilter(model, FilterConfig()).step(state, obstacles, np.zeros(3))
    assert len(info.h) == 1
    _, info = SafetyFilter(model, FilterConfig(ground_z=0.0)).step(state, obstacles,
                                                                   np.zeros(3))
    assert len(info.h) == 2 and info.h[1] > 0


@pytest.mark.parametrize('barrier', ['polyc2bf_horizon', 'polyc2bf_inflated'])
def test_wall_on_the_floor_is_flown_around_or_over_not_under(barrier):
    """A 3 m wall standing on the floor between start and goal: no floor contact, no hit.

    Without the ground the vertical cone's lower ray aims under the wall (z_min = 0) and
    the descending drone hits the floor.
    """
    model = make_model('point_mass_3d', max_accel=3.0)
    obstacles = ObstacleSet.from_obstacles([Obstacle(polygon=WALL, z_min=0.0, z_max=3.0)])
    start = np.array([0.0, 0.0, 0.4, 0.0, 0.0, 0.0])
    goal = np.array([4.0, 0.0, 0.4])
    radius = 0.1
    filt = SafetyFilter(model, FilterConfig(barrier=barrier, robot_radius=radius,
                                            ground_z=0.0, control_period=0.01))
    run = rollout(model, filt, PointMassGoalController(), start, goal, obstacles,
                  duration=15.0)
    heights = run.states[:, 2]
    assert heights.min() - radius > 0.0  # above the floor all the way
    assert run.min_clearance > 0.0
    floor = ObstacleSet.from_obstacles([Obstacle(polygon=WALL, z_min=0.0, z_max=3.0)])
    assert min(clearance(model, s, floor, radius) for s in run.states) > 0.0


def test_descending_onto_the_floor_stops_above_it():
    """A nominal that dives at the floor is held above ground + R."""
    model = make_model('point_mass_3d', max_accel=3.0)
    filt = SafetyFilter(model, FilterConfig(robot_radius=0.1, ground_z=0.0,
                                            control_period=0.01))
    state = np.array([0.0, 0.0, 1.0, 0.0, 0.0, -1.0])
    empty = ObstacleSet.from_obstacles([])
    for _ in range(400):
        u, _ = filt.step(state, empty, np.array([0.0, 0.0, -3.0]))
        state = state + 0.01 * model.state_derivative(state, u)
    assert 0.1 < state[2] < 0.2


SLAB = [Obstacle(polygon=np.array([[2.5, -3.0], [3.5, -3.0], [3.5, 3.0], [2.5, 3.0]]),
                 z_min=1.4, z_max=1.6)]
WINDOW = [Obstacle(polygon=np.array(polygon), z_min=z_min, z_max=z_max) for polygon, z_min, z_max
          in (([[3.0, 0.6], [3.2, 0.6], [3.2, 3.0], [3.0, 3.0]], 0.0, 3.0),
              ([[3.0, -3.0], [3.2, -3.0], [3.2, -0.6], [3.0, -0.6]], 0.0, 3.0),
              ([[3.0, -0.6], [3.2, -0.6], [3.2, 0.6], [3.0, 0.6]], 0.0, 0.7),
              ([[3.0, -0.6], [3.2, -0.6], [3.2, 0.6], [3.0, 0.6]], 1.7, 3.0))]


@pytest.mark.parametrize('world, height', [(SLAB, 1.5), (WINDOW, 1.2)])
def test_quadrotor_rollout_keeps_its_body_clear_of_slab_and_window(world, height):
    """Full 12-state quadrotor (numpy): its body never touches the slab, window or floor.

    The shipped radius about the centre of mass, the ground at 0; the PyBullet runs are in
    test/eval/test_quadrotor_3d.py.
    """
    model = make_model('quadrotor')
    radius = 0.1
    filt = SafetyFilter(model, FilterConfig(robot_radius=radius, ground_z=0.0,
                                            control_period=0.005))
    start = np.zeros(12)
    start[2] = height
    obstacles = ObstacleSet.from_obstacles(world)
    run = rollout(model, filt, QuadrotorGoalController(), start,
                  np.array([6.0, 0.0, height]), obstacles, duration=8.0, physics_step=0.001)
    assert np.isfinite(run.states).all()
    assert run.min_clearance > 0.0
    assert run.states[:, 2].min() > radius
