"""The closed-loop launcher's plan, its failure handling, and the demo launch file (static)."""
import ast
from pathlib import Path

import pytest

from polyc2bf_ros.filter_parameters import load_parameters
from sim_bridge.launcher import (
    AUTO_DOMAINS,
    closed_loop_plan,
    domain_id,
    FILTER_CHOICES,
    LOCKSTEP_FILTER,
    ProcessSpec,
    run_closed_loop,
)
from sim_bridge.lidar import LidarSettings
from sim_bridge.scenario import load_scenario, scenario_names

REPO = Path(__file__).resolve().parents[2]
LAUNCH_FILE = REPO / 'launch' / 'demo.launch.py'


def _console_scripts():
    """Return {executable: module} from setup.py's CONSOLE_SCRIPTS (read, not imported)."""
    tree = ast.parse((REPO / 'setup.py').read_text())
    for node in ast.walk(tree):
        if isinstance(node, ast.Assign) and any(
                getattr(t, 'id', '') == 'CONSOLE_SCRIPTS' for t in node.targets):
            entries = ast.literal_eval(node.value)
    return {name.strip(): target.split(':')[0].strip()
            for name, target in (entry.split('=') for entry in entries)}


@pytest.mark.parametrize('scenario', scenario_names())
def test_plan_for_every_shipped_scenario(scenario):
    """Bridge plus per robot a controller and a filter; executables and files exist."""
    scripts = _console_scripts()
    spec = load_scenario(scenario)
    for barrier in FILTER_CHOICES:
        plan = closed_loop_plan(spec, barrier)
        assert plan[0].executable == 'sim_bridge' and plan[0].parameters['scenario'] == scenario
        per_robot = 1 if barrier == 'none' else 2
        assert len(plan) == 1 + per_robot * len(spec.robots)
        for process in plan:
            assert scripts[process.executable] == process.module
            if process.params_file is not None:
                assert process.params_file.is_file()
        for robot in spec.robots:
            mine = [p for p in plan if p.namespace == robot.name]
            assert [p.executable for p in mine] == (
                ['nominal_controller'] if barrier == 'none'
                else ['nominal_controller', 'safety_filter'])
            assert mine[0].parameters['goal'] == [float(g) for g in robot.goal]
            if barrier == 'none':
                assert mine[0].remappings in ((('cmd_vel_in', 'cmd_vel_out'),),
                                              (('wrench_in', 'wrench_out'),))
            else:
                params = mine[1].parameters
                assert params['filter.barrier'] == barrier
                # The scenarios' rate: the Crazyflie's attitude loop runs at 500 Hz.
                assert params['rate'] == (500.0 if robot.type == 'crazyflie' else 120.0)
                assert LOCKSTEP_FILTER.items() <= params.items()


def test_scan_plan_gives_the_bridge_a_lidar_and_the_filter_its_scans():
    """Scan mode: lidar on, markers off; each filter reads ``scan`` at the mount's pose."""
    lidar = LidarSettings(beams=180, mount=(0.1, 0.0, 0.2), rate=20.0)
    bridge, *nodes = closed_loop_plan('multi_robot_swap', 'polyc2bf_inflated',
                                      obstacle_source='scan', lidar=lidar)
    assert {'lidar.enabled': True, 'obstacle_markers': False, 'lidar.beams': 180,
            'lidar.rate': 20.0, 'lidar.mount': [0.1, 0.0, 0.2]}.items() <= \
        bridge.parameters.items()
    filters = [p for p in nodes if p.executable == 'safety_filter']
    assert len(filters) == 4
    for spec in filters:
        args = spec.ros_args()
        overrides = [args[i + 1] for i, arg in enumerate(args) if arg == '-p']
        values = load_parameters([spec.params_file], overrides, spec.namespace)
        assert values['sensor_pose'] == [0.1, 0.0, 0.2] and values['scan_timeout'] == 0.0
        assert 'scan_topics:=[scan]' in overrides
    markers = closed_loop_plan('long_wall', 'polyc2bf_inflated')[0].parameters
    assert not any(name.startswith('lidar.') or name == 'obstacle_markers' for name in markers)
    with pytest.raises(ValueError, match='obstacle source must be one of markers, scan'):
        closed_loop_plan('long_wall', obstacle_source='radar')


def test_ros_args_spell_parameters_as_ros_does():
    """Namespace, remaps, params file, then -p with YAML lists and lower-case booleans."""
    spec = ProcessSpec('x', 'safety_filter', 'm', 'a1', {'goal': [6.0, 12.0], 'stamped': True,
                                                        'rate': 120.0},
                       Path('/c/quadruped.yaml'), (('cmd_vel_in', 'cmd_vel_out'),))
    assert spec.ros_args() == ['--ros-args', '-r', '__ns:=/a1', '-r', 'cmd_vel_in:=cmd_vel_out',
                               '--params-file', '/c/quadruped.yaml', '-p', 'goal:=[6.0,12.0]',
                               '-p', 'stamped:=true', '-p', 'rate:=120.0']


def test_unknown_filter_is_refused():
    """A filter name outside the four choices raises ValueError listing them."""
    with pytest.raises(ValueError, match='polyc2bf_inflated'):
        closed_loop_plan('long_wall', 'cbf')


def test_domain_is_the_callers_or_picked():
    """ROS_DOMAIN_ID set: used as is; unset or empty: one of AUTO_DOMAINS."""
    assert domain_id({'ROS_DOMAIN_ID': '42'}) == 42
    assert domain_id({}) in AUTO_DOMAINS and domain_id({'ROS_DOMAIN_ID': ' '}) in AUTO_DOMAINS


@pytest.mark.slow
def test_a_node_that_dies_stops_the_run_with_its_log(tmp_path):
    """An invalid filter parameter: the filter exits 1, the run stops with status 1 and why."""
    result = run_closed_loop('long_wall', tmp_path, duration=2.0,
                             filter_parameters={'filter.gamma': -1.0}, timeout=120.0)
    assert result.status == 1 and not result.ok
    assert 'a1_filter (safety_filter) exited with status 1' in result.message
    assert 'gamma' in result.message
    assert set(result.logs) == {'bridge', 'a1_nominal', 'a1_filter'}


def test_launch_file_starts_the_plan_with_launch_ros_nodes():
    """demo.launch.py: Node actions of closed_loop_plan; every argument it reads is declared."""
    tree = ast.parse(LAUNCH_FILE.read_text())
    imports = {(node.module, alias.name) for node in ast.walk(tree)
               if isinstance(node, ast.ImportFrom) for alias in node.names}
    assert {('launch_ros.actions', 'Node'), ('sim_bridge.launcher', 'closed_loop_plan'),
            ('launch', 'LaunchDescription')} <= imports
    calls = [node for node in ast.walk(tree) if isinstance(node, ast.Call)]

    def names(function):
        return {c.args[0].value for c in calls
                if getattr(c.func, 'id', '') == function and c.args
                and isinstance(c.args[0], ast.Constant)}

    assert names('LaunchConfiguration') <= names('DeclareLaunchArgument')
    assert {'scenario', 'filter'} <= names('DeclareLaunchArgument')
    nodes = [c for c in calls if getattr(c.func, 'id', '') == 'Node']
    keywords = {k.arg: k.value for k in nodes[0].keywords}
    assert keywords['package'].value == 'polyc2bf_ros'
    assert {'executable', 'namespace', 'parameters', 'remappings'} <= set(keywords)
    assert "glob('launch/*.py')" in (REPO / 'setup.py').read_text()  # installed to share/


def test_a_scenario_file_is_passed_by_absolute_path(tmp_path, monkeypatch):
    """A relative YAML path still names the file for children started in the run directory."""
    text = (REPO / 'config' / 'scenarios' / 'long_wall.yaml').read_text()
    (tmp_path / 'my_wall.yaml').write_text(text.replace('name: long_wall', 'name: my_wall')
                                           .replace('name: a1', 'name: dog'))
    monkeypatch.chdir(tmp_path)
    plan = closed_loop_plan('my_wall.yaml', 'c3bf')
    assert plan[0].parameters['scenario'] == str(tmp_path / 'my_wall.yaml')
    assert [p.namespace for p in plan[1:]] == ['dog', 'dog']
