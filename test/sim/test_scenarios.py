"""Scenario files: every shipped one loads and runs; bad ones say which field and why."""
import numpy as np
import pytest
import yaml

from polyc2bf_ros.core.geometry.polygons import minimum_enclosing_circle, signed_distance
from polyc2bf_ros.core.models import crazyflie as cf
from sim_bridge.robots import ROBOT_TYPES
from sim_bridge.scenario import load_scenario, SCENARIO_DIR, scenario_from_dict, scenario_names
from sim_bridge.scenario_specs import ScenarioError
from sim_bridge.world import SimWorld

SHIPPED = ('long_wall', 'semi_infinite_wall', 'cluttered', 'tight_gap', 'moving_obstacles',
           'multi_robot_swap', 'quadrotor_pillars', 'quadrotor_wall', 'popup_obstacle',
           'clear_path')


def _minimal():
    """Return a valid one-robot scenario document."""
    return {'name': 'probe', 'duration': 5.0,
            'robots': [{'name': 'a1', 'type': 'quadruped', 'start': [0.0, 0.0, 0.0],
                        'goal': [4.0, 0.0]}],
            'obstacles': [{'polygon': [[2, -1], [2.5, -1], [2.5, 1], [2, 1]]}]}


def test_every_named_scenario_ships():
    """The scenario suite (README, bench/README.md: scenario evaluation) is in config/scenarios."""
    assert set(SHIPPED) <= set(scenario_names()), SCENARIO_DIR


@pytest.mark.parametrize('name', scenario_names())
def test_shipped_scenario_loads_and_steps(name):
    """Each shipped scenario builds a world that runs 300 physics steps with finite states."""
    scenario = load_scenario(name)
    assert scenario.name == name
    assert scenario.duration <= 40.0
    with SimWorld(scenario) as world:
        for robot in scenario.robots:
            if robot.type == 'quadruped':
                world.set_command(robot.name, [0.5, 0.2])
        for _ in range(300):
            world.step()
        for robot in scenario.robots:
            state = world.robot_state(robot.name)
            assert np.isfinite(state).all()
            assert not world.collided(robot.name)
        footprints = world.obstacle_footprints(scenario.robots[0].name)
        present = [o for o in scenario.all_obstacles() if o.appear_at <= world.time]
        assert len(footprints) == len(present) + len(scenario.robots) - 1


def test_load_by_path_equals_load_by_name():
    """A name resolves to config/scenarios/<name>.yaml."""
    by_name = load_scenario('long_wall')
    by_path = load_scenario(SCENARIO_DIR / 'long_wall.yaml')
    assert by_name.name == by_path.name
    np.testing.assert_array_equal(by_name.obstacles[0].polygon, by_path.obstacles[0].polygon)


def test_defaults_are_filled_in():
    """Rates, seed, z range, velocity, obstacle name and robot radius have defaults."""
    scenario = scenario_from_dict(_minimal())
    assert (scenario.physics_rate, scenario.control_rate, scenario.seed) == (240, 120, 0)
    obstacle = scenario.obstacles[0]
    assert obstacle.z == (0.0, 1.0) and not obstacle.moving and obstacle.name == 'obstacle_0'
    assert scenario.robots[0].radius == ROBOT_TYPES['quadruped'].radius == 0.4
    data = _minimal()
    data['robots'][0] = {'name': 'cf', 'type': 'crazyflie', 'start': [0, 0, 1, 0],
                         'goal': [4, 0, 1]}
    assert scenario_from_dict(data).robots[0].radius == cf.BODY_RADIUS


def test_popup_may_cover_the_start_but_not_be_there_at_first():
    """appear_at defaults to 0; a pop-up may cover the start, which the robot has left by then."""
    assert scenario_from_dict(_minimal()).obstacles[0].appear_at == 0.0
    data = _minimal()
    data['obstacles'].append({'polygon': [[-0.5, -0.5], [0.5, -0.5], [0.5, 0.5], [-0.5, 0.5]],
                              'appear_at': 4.5})
    popup = scenario_from_dict(data).obstacles[1]
    assert popup.appear_at == 4.5 and not popup.moving
    data['obstacles'][1]['appear_at'] = 0
    with pytest.raises(ScenarioError, match=r'robots\[0\].start: .* is inside obstacle'):
        scenario_from_dict(data)


def test_popup_scenario_puts_the_box_across_the_path():
    """popup_obstacle: one box appears at t = 3 s straddling y = 0, 1.5-2 m beyond x(3 s)."""
    scenario = load_scenario('popup_obstacle')
    (robot,), (box,) = scenario.robots, scenario.obstacles
    assert box.appear_at == 3.0 and not box.moving
    assert box.polygon[:, 1].min() < -robot.radius and box.polygon[:, 1].max() > robot.radius
    # Accelerating at 1 m/s^2 to the nominal 1 m/s puts the base at x = 2.5 m at t = 3 s.
    assert 1.5 <= box.polygon[:, 0].min() - 2.5 <= 2.0
    assert robot.goal[0] - robot.position[0] >= 9.0


def test_clear_path_keeps_obstacles_well_off_the_path():
    """clear_path: every obstacle is at least 1.5 m to the side of the straight drive."""
    scenario = load_scenario('clear_path')
    (robot,) = scenario.robots
    assert robot.goal[1] == robot.position[1] == 0.0 and robot.goal[0] >= 7.0
    assert scenario.obstacles
    for obstacle in scenario.obstacles:
        assert np.abs(obstacle.polygon[:, 1]).min() >= 1.5
        assert np.all(np.sign(obstacle.polygon[:, 1]) == np.sign(obstacle.polygon[0, 1]))


def _problem(data, tmp_path):
    """Write ``data`` as YAML, load it and return the ScenarioError message."""
    path = tmp_path / 'bad.yaml'
    path.write_text(data if isinstance(data, str) else yaml.safe_dump(data))
    with pytest.raises(ScenarioError) as info:
        load_scenario(path)
    assert str(path) in str(info.value)
    return str(info.value)


def _with(change):
    """Return the minimal document with ``change`` applied to it."""
    data = _minimal()
    change(data)
    return data


def _second_robot(robot):
    """Return a change appending ``robot`` to the robots."""
    return lambda d: d['robots'].append(robot)


BAD = {
    'short start': (
        _second_robot({'name': 'b', 'type': 'quadruped', 'start': [1, 2], 'goal': [0, 3]}),
        'robots[1].start: expected 3 numbers [x, y, yaw] for a quadruped, got 2'),
    'crazyflie goal': (
        _second_robot({'name': 'c', 'type': 'crazyflie', 'start': [0, 3, 1, 0], 'goal': [1, 3]}),
        'robots[1].goal: expected 3 numbers [x, y, z] for a crazyflie, got 2'),
    'unknown type': (
        lambda d: d['robots'][0].update(type='tank'),
        "robots[0].type: expected one of quadruped, diff_drive, jackal, crazyflie, "
        "got 'tank'"),
    'missing goal': (lambda d: d['robots'][0].pop('goal'), 'robots[0].goal: missing'),
    'typo key': (lambda d: d['robots'][0].update(raduis=0.3), 'robots[0].raduis: unknown key'),
    'text number': (lambda d: d.update(duration='long'),
                    "duration: expected a number, got 'long'"),
    'negative duration': (lambda d: d.update(duration=-1), 'duration: must be > 0'),
    'control faster than physics': (
        lambda d: d.update(control_rate=500), 'control_rate: 500.0 Hz exceeds physics_rate'),
    'self-intersecting polygon': (
        lambda d: d['obstacles'][0].update(polygon=[[0, 5], [1, 6], [1, 5], [0, 6]]),
        'obstacles[0].polygon: polygon is self-intersecting'),
    'two-point polygon': (
        lambda d: d['obstacles'][0].update(polygon=[[0, 5], [1, 6]]),
        'obstacles[0].polygon: polygon needs at least 3 distinct points'),
    'inverted z': (lambda d: d['obstacles'][0].update(z=[2, 1]),
                   'obstacles[0].z: min must be below max, got [2.0, 1.0]'),
    'velocity size': (lambda d: d['obstacles'][0].update(velocity=[1, 0, 0]),
                      'obstacles[0].velocity: expected 2 numbers [vx, vy], got 3'),
    'negative appear_at': (lambda d: d['obstacles'][0].update(appear_at=-1.0),
                           'obstacles[0].appear_at: must be >= 0.0, got -1.0'),
    'text appear_at': (lambda d: d['obstacles'][0].update(appear_at='soon'),
                       "obstacles[0].appear_at: expected a number, got 'soon'"),
    'goal inside a pop-up': (
        lambda d: d['obstacles'][0].update(appear_at=2.0, polygon=[[3.5, -1], [4.5, -1],
                                                                   [4.5, 1], [3.5, 1]]),
        "robots[0].goal: [4.0, 0.0] is inside obstacle 'obstacle_0'"),
    'start inside obstacle': (
        lambda d: d['robots'][0].update(start=[2.2, 0.0, 0.0]),
        "robots[0].start: [2.2, 0.0] is inside obstacle 'obstacle_0'"),
    'goal too close': (
        lambda d: d['robots'][0].update(goal=[2.7, 0.0]),
        "robots[0].goal: [2.7, 0.0] is 0.200 m from obstacle 'obstacle_0'"),
    'duplicate name': (
        _second_robot({'name': 'a1', 'type': 'quadruped', 'start': [0, 3, 0], 'goal': [1, 3]}),
        "robots[1].name: duplicate robot name 'a1'"),
    'no robots': (lambda d: d.update(robots=[]), 'robots: expected a non-empty list'),
    'random region': (
        lambda d: d.update(random_obstacles={'count': 3, 'region': [[5, 5], [0, 0]],
                                             'size': [0.2, 0.5], 'height': [1, 2],
                                             'clearance': 0.5}),
        'random_obstacles.region: the first corner must be below-left of the second'),
    'random overfull': (
        lambda d: d.update(random_obstacles={'count': 20, 'region': [[5, 5], [6, 6]],
                                             'size': [0.5, 0.6], 'height': [1, 2],
                                             'clearance': 0.5, 'spacing': 0.5}),
        'random_obstacles.count: placed only'),
}


@pytest.mark.parametrize('case', sorted(BAD))
def test_bad_scenario_names_field_and_problem(case, tmp_path):
    """Each invalid document is rejected with its field path and the reason."""
    change, expected = BAD[case]
    assert expected in _problem(_with(change), tmp_path)


def test_unreadable_files_are_scenario_errors(tmp_path):
    """Invalid YAML, a non-mapping document and a missing file or name all raise ScenarioError."""
    assert 'not valid YAML' in _problem('name: [unclosed', tmp_path)
    assert 'document: expected a mapping, got list' in _problem('- 1\n- 2\n', tmp_path)
    with pytest.raises(ScenarioError, match='cannot read'):
        load_scenario(tmp_path / 'absent.yaml')
    with pytest.raises(ScenarioError, match="no scenario named 'nowhere'.*long_wall"):
        load_scenario('nowhere')


def test_random_obstacles_are_seeded_and_keep_clear():
    """Same seed, same polygons; another seed, others; starts and goals stay clear."""
    scenario = load_scenario('cluttered')
    first = scenario.all_obstacles()
    again = scenario.with_seed(scenario.seed).all_obstacles()
    other = scenario.with_seed(scenario.seed + 1).all_obstacles()
    assert len(first) == scenario.random_obstacles.count == 30
    for a, b in zip(first, again):
        np.testing.assert_array_equal(a.polygon, b.polygon)
    assert any(a.polygon.shape != b.polygon.shape or not np.allclose(a.polygon, b.polygon)
               for a, b in zip(first, other))
    robot = scenario.robots[0]
    for obstacle in first:
        for point in (robot.position, robot.goal):
            assert signed_distance(point, obstacle.polygon) >= scenario.random_obstacles.clearance


@pytest.mark.parametrize('name', ['long_wall', 'semi_infinite_wall', 'quadrotor_wall'])
def test_wall_scenarios_start_inside_the_circumscribed_circle(name):
    """The C3BF failure geometry: the start lies inside the wall's enclosing circle."""
    scenario = load_scenario(name)
    centre, radius = minimum_enclosing_circle(scenario.obstacles[0].polygon)
    start = scenario.robots[0].position[:2]
    assert np.linalg.norm(start - centre) < radius - 0.5


def test_tight_gap_is_closed_for_circles_open_for_polygons():
    """Circles around the blocks leave less than a robot diameter; the polygons leave more."""
    scenario = load_scenario('tight_gap')
    blocks = sorted((o.polygon for o in scenario.obstacles if o.name.startswith('block')),
                    key=lambda b: b[:, 1].mean())
    lower, upper = blocks
    x = upper[:, 0].mean()
    (lower_c, lower_r), (upper_c, upper_r) = map(minimum_enclosing_circle, blocks)
    circle_gap = ((upper_c[1] - np.sqrt(upper_r ** 2 - (x - upper_c[0]) ** 2))
                  - (lower_c[1] + np.sqrt(lower_r ** 2 - (x - lower_c[0]) ** 2)))
    diameter = 2 * 0.35
    assert circle_gap < diameter < upper[:, 1].min() - lower[:, 1].max()
