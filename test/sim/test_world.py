"""PyBullet world: plants against the core models, clearances, collisions, determinism."""
import json

import numpy as np
import pybullet as pb
import pytest

from polyc2bf_ros.core.geometry.polygons import signed_distance
from polyc2bf_ros.core.models import crazyflie as cf, make_model
from sim_bridge.metrics import RunMetrics
from sim_bridge.nominal import QuadrotorGoalController, UnicycleGoalController
from sim_bridge.plants import A1_STANDING_POSE, CRAZYFLIE_HALF_HEIGHT, QUADRUPED_MAX_ACCEL
from sim_bridge.rollout import rk4_step
from sim_bridge.scenario import load_scenario, scenario_from_dict
from sim_bridge.world import COLLISION_TOLERANCE, SimWorld

WALL = [[2.0, -2.0], [2.2, -2.0], [2.2, 2.0], [2.0, 2.0]]


def _world(robots, obstacles=(), **extra):
    """Return a SimWorld of a scenario built from robot and obstacle dicts."""
    return SimWorld(scenario_from_dict({'name': 'probe', 'duration': 10.0, 'robots': robots,
                                        'obstacles': list(obstacles), **extra}))


def _crazyflie(start=(0.0, 0.0, 1.0, 0.0), goal=None):
    """Return a crazyflie robot dict."""
    return {'name': 'cf', 'type': 'crazyflie', 'start': list(start),
            'goal': list(goal or start[:3])}


def _quadruped(name='a1', start=(0.0, 0.0, 0.0), goal=(5.0, 0.0)):
    """Return a quadruped robot dict."""
    return {'name': name, 'type': 'quadruped', 'start': list(start), 'goal': list(goal)}


def _run(world, seconds, control=None, rate=100.0):
    """Step ``seconds``; call ``control()`` every 1/rate s (zero-order hold in between)."""
    next_control = 0.0
    for _ in range(int(round(seconds / world.dt))):
        if control is not None and world.time >= next_control - 1e-9:
            control()
            next_control += 1.0 / rate
        world.step()


def test_crazyflie_hovers_under_the_goal_controller():
    """Wrench -> thrusts through the mixer holds 1 m altitude within 2 cm after 3 s."""
    controller = QuadrotorGoalController()
    goal = np.array([0.0, 0.0, 1.0])
    with _world([_crazyflie(start=(0.0, 0.0, 0.9, 0.2), goal=goal.tolist())]) as world:
        _run(world, 3.0, lambda: world.set_command(
            'cf', cf.thrusts_from_wrench(controller.wrench(world.robot_state('cf'), goal))))
        state = world.robot_state('cf')
    assert abs(state[2] - 1.0) < 0.02
    assert np.linalg.norm(state[:2]) < 0.02 and np.linalg.norm(state[3:6]) < 0.05


def test_wrench_command_is_the_mixer_inverse():
    """Kind 'wrench' applies M^-1 [T, tau], the same as the equivalent thrusts."""
    wrench = np.array([cf.MASS * cf.GRAVITY, 1e-5, -2e-5, 1e-6])
    states = []
    for kind, cmd in (('wrench', wrench), ('thrusts', cf.thrusts_from_wrench(wrench))):
        with _world([_crazyflie()]) as world:
            world.set_command('cf', cmd, kind)
            _run(world, 0.2)
            states.append(world.robot_state('cf'))
    np.testing.assert_allclose(states[0], states[1], atol=1e-12)


@pytest.mark.parametrize('rotor', range(4))
def test_single_rotor_tilts_the_way_the_mixer_says(rotor):
    """Extra thrust on one rotor: body angular acceleration signs equal those of I^-1 M df."""
    extra = np.zeros(4)
    extra[rotor] = 0.2 * cf.HOVER_ROTOR_THRUST
    expected = np.linalg.solve(cf.INERTIA, cf.wrench_from_thrusts(extra)[1:])
    with _world([_crazyflie(start=(0.0, 0.0, 1.0, 0.7))]) as world:
        world.set_command('cf', np.full(4, cf.HOVER_ROTOR_THRUST) + extra)
        world.step()
        rates = world.robot_state('cf')[9:12]
    np.testing.assert_array_equal(np.sign(rates), np.sign(expected))
    np.testing.assert_allclose(rates / world.dt, expected, rtol=0.05)
    if rotor == 0:  # front-right: rolls right (tau_x < 0) and pitches nose up (tau_y < 0)
        assert rates[0] < 0 and rates[1] < 0


def test_crazyflie_follows_the_core_quadrotor_model():
    """Uneven thrusts for 0.5 s: PyBullet and the core model's RK4 agree (same conventions)."""
    model = make_model('quadrotor')
    thrusts = np.array([1.02, 0.99, 1.0, 0.985]) * cf.HOVER_ROTOR_THRUST
    with _world([_crazyflie(start=(0.0, 0.0, 1.0, 0.3))]) as world:
        world.set_command('cf', thrusts)
        state = world.robot_state('cf')
        for _ in range(120):
            world.step()
            for _ in range(4):
                state = rk4_step(model, state, thrusts, world.dt / 4)
        simulated = world.robot_state('cf')
    assert np.linalg.norm(simulated[6:9]) > 0.5  # it really tumbled
    np.testing.assert_allclose(simulated, state, atol=0.01)


def test_quadruped_tracks_a_velocity_command():
    """[v, omega] is reached at the acceleration limit and then held exactly; pose matches."""
    with _world([_quadruped()]) as world:
        world.set_command('a1', [0.8, 0.5])
        _run(world, 0.2)
        v_early = world.robot_state('a1')[3]
        _run(world, 1.8)
        state = world.robot_state('a1')
        position, quaternion = world.robot_pose('a1')
        legs = world.joint_positions('a1')
    assert v_early == pytest.approx(QUADRUPED_MAX_ACCEL * 0.2, abs=0.01)
    np.testing.assert_allclose(state[3:], [0.8, 0.5], atol=1e-9)
    np.testing.assert_allclose(position[:2], state[:2])
    roll, pitch, yaw = pb.getEulerFromQuaternion(quaternion)
    assert abs(roll) < 1e-9 and abs(pitch) < 1e-9
    assert yaw == pytest.approx(state[2])
    assert 0.2 < position[2] < 0.35  # standing, not sunk by gravity
    names = [f'{leg}_{part}_joint' for leg in ('FR', 'FL', 'RR', 'RL')
             for part in ('hip', 'upper', 'lower')]
    assert sorted(legs) == sorted(names)  # turning at 0.5 rad/s never moved them:
    np.testing.assert_allclose([legs[n] for n in names], A1_STANDING_POSE * 4, atol=1e-9)


def test_quadruped_follows_the_core_unicycle_model():
    """Acceleration commands within the limits integrate like the core unicycle model."""
    model = make_model('unicycle')
    state = np.zeros(5)
    with _world([_quadruped()]) as world:
        for u in ([1.0, 0.5], [0.5, -1.0], [-0.5, 0.2]):
            world.set_command('a1', u, 'acceleration')
            for _ in range(120):
                world.step()
                state = rk4_step(model, state, np.array(u), world.dt)
        np.testing.assert_allclose(world.robot_state('a1'), state, atol=1e-3)


def test_quadruped_into_a_wall_is_a_collision():
    """Driven at a wall with no filter, collided() turns True and the metrics record it."""
    with _world([_quadruped()], [{'polygon': WALL, 'name': 'wall'}]) as world:
        metrics = RunMetrics(world)
        world.set_command('a1', [1.0, 0.0])
        _run(world, 0.8, metrics.update)
        assert not world.collided('a1') and not metrics.robots['a1'].collision
        _run(world, 1.7, metrics.update)
        assert world.collided('a1')
        record = metrics.to_json()['a1']
    assert record['collision'] and record['min_clearance_m'] < -COLLISION_TOLERANCE
    assert not record['goal_reached'] and record['time_to_goal_s'] is None
    json.dumps(record)


def test_crazyflie_crash_is_a_collision():
    """Flown at a wall by the goal controller alone, the Crazyflie's crash is recorded."""
    controller = QuadrotorGoalController()
    goal = np.array([4.0, 0.0, 1.0])
    with _world([_crazyflie(goal=goal.tolist())], [{'polygon': WALL, 'z': [0, 2]}]) as world:
        metrics = RunMetrics(world)

        def control():
            world.set_command('cf', controller(world.robot_state('cf'), goal))
            metrics.update()
        _run(world, 4.0, control)
    assert metrics.robots['cf'].collision
    assert 2.0 < metrics.robots['cf'].collision_time_s < 4.0


def test_metrics_goal_time_and_path_length():
    """An unobstructed drive: goal reached, time and path length as integrated."""
    controller = UnicycleGoalController()
    goal = np.array([3.0, 0.0])
    with _world([_quadruped(goal=goal.tolist())]) as world:
        metrics = RunMetrics(world)

        def control():
            world.set_command('a1', controller.velocity_command(world.robot_state('a1'), goal))
            metrics.update()
        _run(world, 6.0, control)
        record = metrics.to_json()['a1']
        travelled = world.robot_state('a1')[0]
    assert record['goal_reached'] and not record['collision']
    assert 2.5 < record['time_to_goal_s'] < 6.0
    assert travelled > 2.75 and record['path_length_m'] == pytest.approx(travelled, abs=1e-3)
    assert record['min_clearance_m'] is None  # nothing ever within range


def test_clearance_matches_the_analytic_box_distance():
    """Crazyflie cylinder beside and above a box: distance = gap minus radius / half height."""
    box = [[1.0, -0.5], [1.4, -0.5], [1.4, 0.5], [1.0, 0.5]]
    cases = [((0.5, 0.0, 0.5, 0.0), 1.0 - 0.5 - cf.BODY_RADIUS),
             ((1.2, 0.0, 1.3, 0.0), 1.3 - CRAZYFLIE_HALF_HEIGHT - 1.0)]
    for start, expected in cases:
        with _world([_crazyflie(start=start)], [{'polygon': box, 'z': [0, 1]}]) as world:
            assert world.clearances('cf')[0] == pytest.approx(expected, abs=1e-4)


def test_clearance_follows_moving_and_non_convex_obstacles():
    """A translating box and an L-shaped obstacle's notch give the analytic distances."""
    l_shape = [[3.0, -1.0], [5.0, -1.0], [5.0, 1.0], [4.0, 1.0], [4.0, 0.0], [3.0, 0.0]]
    moving = {'polygon': [[-2.0, -0.2], [-1.6, -0.2], [-1.6, 0.2], [-2.0, 0.2]],
              'velocity': [0.5, 0.0], 'name': 'mover'}
    start = (3.4, 0.5, 0.5, 0.0)  # in the notch: 0.5 m from the foot, 0.6 m from the leg
    with _world([_crazyflie(start=start)], [{'polygon': l_shape}, moving]) as world:
        notch = world.clearances('cf')[0]
        _run(world, 2.0)
        footprint = world.obstacle_footprints('cf')[1]
        x, y = world.robot_state('cf')[:2]
        mover = world.clearances('cf', max_distance=5.0)[1]
    assert notch == pytest.approx(0.5 - cf.BODY_RADIUS, abs=1e-4)
    np.testing.assert_allclose(footprint.polygon[:, 0].max(), -1.6 + 1.0)
    np.testing.assert_allclose(footprint.velocity, [0.5, 0.0, 0.0])
    corner = np.array([-1.6, 0.2]) + [1.0, 0.0]  # the nearest corner after 2 s at 0.5 m/s
    assert mover == pytest.approx(np.hypot(x - corner[0], y - corner[1]) - cf.BODY_RADIUS,
                                  abs=1e-3)  # GJK on a cylinder against a corner


def test_footprints_list_obstacles_then_other_robots():
    """Each robot sees every obstacle and every other robot's circle, never itself."""
    robots = [_quadruped('a', (0, 0, 0), (1, 0)), _quadruped('b', (0, 3, 0), (1, 3)),
              _crazyflie(start=(3.0, 3.0, 1.0, 0.0))]
    with _world(robots, [{'polygon': WALL, 'name': 'wall'}]) as world:
        world.set_command('b', [1.0, 0.0])
        _run(world, 1.0)
        footprints = world.obstacle_footprints('a')
        clearances = world.clearances('a', max_distance=5.0)
        default_range = world.clearances('a')
        state_b = world.robot_state('b')
    assert [f.name for f in footprints] == ['wall', 'b', 'cf']
    assert [f.robot for f in footprints] == [False, True, True]
    b = footprints[1]
    np.testing.assert_allclose(np.linalg.norm(b.polygon - state_b[:2], axis=1), 0.4)
    np.testing.assert_allclose(b.velocity, [1.0, 0.0, 0.0])
    assert signed_distance(state_b[:2], b.polygon) < 0
    assert footprints[2].z_min < 1.0 < footprints[2].z_max
    assert clearances.shape == (3,) and np.isfinite(clearances[:2]).all()
    assert 2.0 < clearances[1] < 3.0  # A1 bodies 3 m apart
    assert np.isinf(default_range).all()  # beyond CLEARANCE_RANGE


def test_same_commands_give_identical_states():
    """Two runs of a scenario with the same command sequence are bit-identical."""
    scenario = load_scenario('moving_obstacles')
    scenario = scenario_from_dict({
        'name': 'mixed', 'duration': 5.0,
        'robots': [_quadruped(), _crazyflie(start=(0.0, 3.0, 1.0, 0.0))],
        'obstacles': [{'polygon': o.polygon.tolist(), 'velocity': o.velocity.tolist()}
                      for o in scenario.obstacles]})
    commands = np.random.default_rng(3).uniform(-1.0, 1.0, size=(100, 6))
    runs = []
    for _ in range(2):
        with SimWorld(scenario) as world:
            trace = []
            for row in commands:
                world.set_command('a1', row[:2])
                world.set_command('cf', cf.HOVER_ROTOR_THRUST * (1.0 + 0.05 * row[2:]))
                for _ in range(3):
                    world.step()
                trace.append(np.concatenate([world.robot_state('a1'),
                                             world.robot_state('cf'),
                                             world.clearances('a1')]))
            runs.append(np.array(trace))
    np.testing.assert_array_equal(runs[0], runs[1])


def test_bad_commands_are_rejected():
    """Unknown kinds, wrong sizes and NaN raise ValueError; the held command is kept."""
    with _world([_quadruped(), _crazyflie(start=(0.0, 3.0, 1.0, 0.0))]) as world:
        with pytest.raises(ValueError, match='velocity or acceleration'):
            world.set_command('a1', [1.0, 0.0], 'thrusts')
        with pytest.raises(ValueError, match='2 finite numbers'):
            world.set_command('a1', [1.0, np.nan])
        with pytest.raises(ValueError, match='4 finite numbers'):
            world.set_command('cf', [0.1, 0.1, 0.1])
        with pytest.raises(KeyError):
            world.set_command('nobody', [0.0, 0.0])
        world.step()
        assert world.robot_state('a1')[3] == 0.0
        assert world.joint_positions('cf') == {}
        world.close()
        world.close()


def test_popup_obstacle_is_absent_until_it_appears():
    """Before appear_at: no footprint, clearance or collision; from then on all three."""
    box = {'polygon': [[0.6, -0.5], [1.0, -0.5], [1.0, 0.5], [0.6, 0.5]], 'name': 'popup',
           'appear_at': 1.0}
    with _world([_quadruped()], [box]) as world:
        metrics = RunMetrics(world)
        world.set_command('a1', [1.0, 0.0])
        _run(world, 1.0 - world.dt, metrics.update)  # drives into where the box will be
        assert world.robot_state('a1')[0] > 0.6
        assert world.obstacle_footprints('a1') == [] and world.obstacle_version == 0
        assert world.clearances('a1', max_distance=5.0).shape == (0,)
        assert not world.collided('a1') and not metrics.robots['a1'].collision
        world.step()  # t = 1.0: it appears around the robot
        footprints = world.obstacle_footprints('a1')
        assert [(f.name, f.index) for f in footprints] == [('popup', 0)]
        assert world.obstacle_version == 1
        assert world.collided('a1')
        metrics.update()
    assert metrics.robots['a1'].collision and metrics.robots['a1'].collision_time_s == 1.0


def test_moving_popup_starts_from_its_polygon_at_appear_at():
    """A moving pop-up's polygon is its footprint at appear_at; it moves on from there."""
    square = [[3.0, 3.0], [3.4, 3.0], [3.4, 3.4], [3.0, 3.4]]
    obstacles = [{'polygon': WALL, 'name': 'wall'},
                 {'polygon': square, 'velocity': [0.0, -1.0], 'appear_at': 0.5}]
    with _world([_crazyflie(start=(3.2, 0.0, 0.5, 0.0))], obstacles) as world:
        _run(world, 0.5)
        at_appearance = world.obstacle_footprints('cf')[1]
        _run(world, 1.5)
        later = world.obstacle_footprints('cf')[1]
        clearance = world.clearances('cf', max_distance=5.0)[1]
    np.testing.assert_allclose(at_appearance.polygon, square)
    np.testing.assert_allclose(later.polygon, np.array(square) + [0.0, -1.5])
    assert later.index == 1 and later.name == 'obstacle_1'
    # Its lower face is at y = 1.5 after 1.5 s; the Crazyflie holds hover thrust near y = 0.
    assert clearance == pytest.approx(1.5 - cf.BODY_RADIUS, abs=0.02)


def test_quadruped_world_without_bullet_steps_measures_the_same():
    """Quadrupeds only: skipping Bullet's step changes no state and no clearance (to 1e-12)."""
    scenario = load_scenario('cluttered')
    robot = scenario.robots[0].name
    commands = np.random.default_rng(0).uniform([-0.5, -2.0], [2.0, 2.0], size=(25, 2))
    traces = []
    for bullet_steps in (False, True):
        with SimWorld(scenario) as world:
            assert world._bullet_steps is False
            world._bullet_steps = bullet_steps
            trace = []
            for command in commands:
                world.set_command(robot, command)
                for _ in range(24):
                    world.step()
                trace.append(np.concatenate([world.robot_state(robot),
                                             world.clearances(robot, max_distance=5.0)]))
            traces.append(np.array(trace))
    assert np.isfinite(traces[0][:, 5:]).sum() > 100  # many obstacles within 5 m
    np.testing.assert_allclose(traces[0], traces[1], rtol=0.0, atol=1e-12)


def test_body_twist_is_the_state_velocity_in_the_body_frame():
    """Quadruped: (v, 0, 0, 0, 0, omega); Crazyflie: R^T v_world and the body rates."""
    thrusts = np.array([1.02, 0.99, 1.0, 0.985]) * cf.HOVER_ROTOR_THRUST
    robots = [_quadruped(), _crazyflie(start=(0.0, 3.0, 1.0, 0.3))]
    with _world(robots) as world:
        world.set_command('a1', [0.8, 0.5])
        world.set_command('cf', thrusts)
        _run(world, 0.5)
        quadruped, crazyflie = world.robot_state('a1'), world.robot_state('cf')
        assert world.body_twist('a1') == (quadruped[3], 0.0, 0.0, 0.0, 0.0, quadruped[4])
        twist = np.array(world.body_twist('cf'))
        rotation = np.reshape(pb.getMatrixFromQuaternion(world.robot_pose('cf')[1]), (3, 3))
    assert np.linalg.norm(crazyflie[6:8]) > 0.05  # tilted, so the frames differ
    np.testing.assert_allclose(rotation @ twist[:3], crazyflie[3:6], atol=1e-12)
    np.testing.assert_allclose(twist[3:], crazyflie[9:12], atol=1e-12)
