"""Diff-drive base: its plant, its PyBullet disc, cylinder obstacles and exact clearances."""
import math

import numpy as np
import pybullet as pb
import pytest

from polyc2bf_ros.filter_parameters import build_filter, load_parameters
from sim_bridge.closed_loop import run_in_process
from sim_bridge.launcher import body_parameters, closed_loop_plan, params_file
from sim_bridge.metrics import RunMetrics
from sim_bridge.plants import DIFF_DRIVE_HEIGHT, QUADRUPED_MAX_ACCEL, QUADRUPED_MAX_ANGULAR_ACCEL
from sim_bridge.scenario import scenario_from_dict
from sim_bridge.scenario_specs import cylinder_polygon
from sim_bridge.world import COLLISION_TOLERANCE, SimWorld

CYLINDER = {'cylinder': [3.0, 0.0], 'radius': 0.075, 'name': 'post'}


def _scenario(radius=None, obstacles=(CYLINDER,), **robot):
    """Return a scenario with one diff-drive base ``base`` at the origin facing +x."""
    spec = {'name': 'base', 'type': 'diff_drive', 'start': [0.0, 0.0, 0.0], 'goal': [5.0, 0.0],
            **robot}
    if radius is not None:
        spec['radius'] = radius
    return scenario_from_dict({'name': 'probe', 'duration': 10.0, 'robots': [spec],
                               'obstacles': list(obstacles)})


def _run(world, seconds, each_period=None, rate=120.0):
    """Step ``seconds``; call ``each_period()`` after every 1/rate s."""
    per_period = round(world.scenario.physics_rate / rate)
    for _ in range(round(seconds * rate)):
        for _ in range(per_period):
            world.step()
        if each_period is not None:
            each_period()


def _ramped_unicycle(v, omega, seconds, dt=1e-4):
    """Integrate x' = v(t) cos(theta), y' = v(t) sin(theta), theta' = omega(t) finely.

    v(t) and omega(t) ramp at the plant's limits to the commanded values.
    """
    x = y = theta = 0.0
    for k in range(round(seconds / dt)):
        t = (k + 0.5) * dt
        speed = min(QUADRUPED_MAX_ACCEL * t, v)
        theta += min(QUADRUPED_MAX_ANGULAR_ACCEL * t, omega) * dt
        x, y = x + speed * math.cos(theta) * dt, y + speed * math.sin(theta) * dt
    return np.array([x, y, theta])


def test_plant_tracks_a_velocity_command():
    """[v, omega] is reached at the acceleration limits, then held; the pose is the unicycle's."""
    with SimWorld(_scenario(obstacles=())) as world:
        world.set_command('base', [0.6, 0.4])
        _run(world, 0.2)
        v_early = world.robot_state('base')[3]
        _run(world, 2.8)
        state = world.robot_state('base')
        position, quaternion = world.robot_pose('base')
        twist = world.body_twist('base')
    assert v_early == pytest.approx(QUADRUPED_MAX_ACCEL * 0.2, abs=0.01)
    np.testing.assert_allclose(state[3:], [0.6, 0.4], atol=1e-9)
    np.testing.assert_allclose(state[:3], _ramped_unicycle(0.6, 0.4, 3.0), atol=2e-3)
    np.testing.assert_allclose(position, [state[0], state[1], 0.5 * DIFF_DRIVE_HEIGHT])
    roll, pitch, yaw = pb.getEulerFromQuaternion(quaternion)
    assert abs(roll) < 1e-9 and abs(pitch) < 1e-9 and yaw == pytest.approx(state[2])
    assert twist == pytest.approx((0.6, 0.0, 0.0, 0.0, 0.0, 0.4))


@pytest.mark.parametrize('radius', [0.2, 0.35])
def test_driven_into_a_cylinder_is_a_collision(radius):
    """Clearance is PyBullet's between the true cylinders; contact turns it into a collision."""
    with SimWorld(_scenario(radius)) as world:
        metrics = RunMetrics(world)
        world.set_command('base', [1.0, 0.0])
        gaps = []

        def sample():
            metrics.update()
            x = world.robot_state('base')[0]
            gaps.append((3.0 - x - 0.075 - radius, world.min_clearance('base')))

        _run(world, 1.5, sample)
        assert not world.collided('base') and not metrics.robots['base'].collision
        _run(world, 1.5, sample)
        assert world.collided('base')
        record = metrics.to_json()['base']
    assert record['collision'] and record['min_clearance_m'] < -COLLISION_TOLERANCE
    near = [(exact, measured) for exact, measured in gaps if -0.05 < exact < 0.4]
    assert len(near) > 20  # the disc's size is the scenario's radius, the post a cylinder
    np.testing.assert_allclose(*np.array(near).T, atol=2e-3)


def test_min_clearance_is_the_minimum_of_all_clearances():
    """Nearest-first with early stop, and the near list kept while nothing moves: same value."""
    posts = [{'cylinder': [1.0 + 0.4 * i, 0.3 * (-1) ** i], 'radius': 0.1} for i in range(8)]
    moving = {'polygon': [[2.0, 1.0], [2.4, 1.0], [2.4, 1.4], [2.0, 1.4]],
              'velocity': [0.0, -0.2]}
    for obstacles in (posts, posts + [moving]):
        with SimWorld(_scenario(obstacles=obstacles)) as world:
            world.set_command('base', [0.5, 0.2])
            checks = []
            _run(world, 6.0, lambda: checks.append(
                (world.min_clearance('base'),
                 min(world.clearances('base').tolist(), default=math.inf))))
        finite = [(a, b) for a, b in checks if math.isfinite(b)]
        assert len(finite) > 100 and all(a == b for a, b in checks)


def test_cylinders_in_scenario_files():
    """A cylinder is its circumscribed 12-gon for the filter; its fields are checked."""
    scenario = _scenario(path=[[0.0, 0.0], [2.0, 1.0], [5.0, 0.0]])
    (post,) = scenario.obstacles
    assert post.radius == 0.075 and post.polygon.shape == (12, 2)
    np.testing.assert_allclose(post.polygon, cylinder_polygon([3.0, 0.0], 0.075))
    np.testing.assert_allclose(np.linalg.norm(post.polygon - [3.0, 0.0], axis=1),
                               0.075 / math.cos(math.pi / 12))
    assert scenario.robots[0].radius == 0.2
    np.testing.assert_allclose(scenario.robots[0].path, [[0, 0], [2, 1], [5, 0]])
    with pytest.raises(ValueError, match=r'obstacles\[0\].radius: missing'):
        _scenario(obstacles=[{'cylinder': [3.0, 0.0]}])
    with pytest.raises(ValueError, match=r'robots\[0\].path\[1\]: expected 2 numbers'):
        _scenario(path=[[0.0, 0.0], [1.0]])


def test_filter_radius_covers_the_disc_from_the_guarded_point():
    """robot_radius = the disc radius; the filter guards offset_l ahead with radius + offset_l.

    In process and in the launcher's plan.
    """
    scenario = _scenario(0.3)
    overrides = body_parameters(scenario.robots[0])
    assert overrides == {'filter.robot_radius': pytest.approx(0.3)}
    run = run_in_process(scenario, 'polyc2bf_inflated', duration=0.5)
    assert run.robot_radius == pytest.approx(0.3)
    settings = build_filter({**load_parameters([params_file('diff_drive')], (), ''),
                             **overrides})
    assert settings.command_filter.safety_filter.guard_radius == pytest.approx(0.31)
    (filter_spec,) = [p for p in closed_loop_plan(scenario, 'polyc2bf_inflated')
                      if p.executable == 'safety_filter']
    assert filter_spec.params_file.name == 'diff_drive.yaml'
    assert filter_spec.parameters['filter.robot_radius'] == pytest.approx(0.3)
