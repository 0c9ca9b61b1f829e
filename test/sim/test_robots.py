"""The robot registry is complete: every type has its config, plant, message and controller."""
import pytest
import yaml

from sim_bridge import launcher, plants
from sim_bridge.bag_reader import message_class
from sim_bridge.robots import robot_type, ROBOT_TYPES
from sim_bridge.scenario import scenario_from_dict
from sim_bridge.scenario_specs import ScenarioError


def _scenario(types):
    """Return a scenario document with one robot of each type, 2 m apart."""
    robots = []
    for i, name in enumerate(types):
        size = ROBOT_TYPES[name].goal_size if name in ROBOT_TYPES else 2
        start = [2.0 * i, 0.0] + [1.0] * (size - 2) + [0.0]
        goal = [2.0 * i, 5.0] + [1.0] * (size - 2)
        robots.append({'name': f'r{i}', 'type': name, 'start': start, 'goal': goal})
    return {'name': 'registry', 'duration': 1.0, 'robots': robots}


@pytest.mark.parametrize('name', ROBOT_TYPES)
def test_every_type_has_config_plant_message_and_controller(name):
    """Its shipped parameter file runs its model; its plant, message and controller exist."""
    robot = robot_type(name)
    assert robot.name == name
    config = yaml.safe_load(launcher.params_file(name).read_text())
    assert config['/**/safety_filter']['ros__parameters']['model'] == robot.model
    assert robot.command_kind in plants.PLANTS[name].COMMAND_KINDS
    assert message_class(robot.command_type).__name__.endswith('Stamped')
    method = 'velocity_command' if robot.command_kind == 'velocity' else 'wrench'
    assert callable(getattr(robot.goal_controller(), method))


def test_world_has_exactly_the_registry_plants():
    """The world builds a plant for every registered type and for no other."""
    assert set(plants.PLANTS) == set(ROBOT_TYPES)


def test_loader_and_launcher_accept_exactly_the_registry_types(tmp_path):
    """Every registered type loads and plans with its parameter file; others are refused."""
    document = _scenario(list(ROBOT_TYPES))
    scenario = scenario_from_dict(document)
    assert [r.type for r in scenario.robots] == list(ROBOT_TYPES)
    path = tmp_path / 'registry.yaml'
    path.write_text(yaml.safe_dump(document))
    plan = launcher.closed_loop_plan(str(path))
    filters = {spec.namespace: spec for spec in plan if spec.executable == 'safety_filter'}
    for robot in scenario.robots:
        assert filters[robot.name].params_file == launcher.params_file(robot.type)
    valid = ', '.join(ROBOT_TYPES)
    with pytest.raises(ScenarioError, match=f'expected one of {valid}, got .tank.'):
        scenario_from_dict(_scenario(['tank']))
    with pytest.raises(ValueError, match=f'expected one of {valid}, got .tank.'):
        launcher.params_file('tank')
