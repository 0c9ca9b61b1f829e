"""``nav2_safety_filter.launch.py`` and its parameters, read statically (no launch packages)."""
import ast
from pathlib import Path

from polyc2bf_ros.filter_parameters import build_filter, load_parameters

REPO = Path(__file__).resolve().parents[2]
LAUNCH_FILE = REPO / 'launch' / 'nav2_safety_filter.launch.py'
PARAMS_FILE = REPO / 'config' / 'nav2_safety_filter.yaml'


def _calls(function):
    """Return the calls of ``function`` (by name) in the launch file."""
    return [node for node in ast.walk(ast.parse(LAUNCH_FILE.read_text()))
            if isinstance(node, ast.Call) and getattr(node.func, 'id', '') == function]


def _arguments():
    """Return ``{name: default}`` of the declared launch arguments (None if not a literal)."""
    arguments = {}
    for call in _calls('DeclareLaunchArgument'):
        default = next(k.value for k in call.keywords if k.arg == 'default_value')
        arguments[call.args[0].value] = getattr(default, 'value', None)
    return arguments


def test_arguments_are_declared_with_nav2_defaults():
    """Every argument read is declared; the Nav2 ones default as Nav2's bringup does."""
    arguments = _arguments()
    read = {c.args[0].value for c in _calls('LaunchConfiguration')}
    assert read <= set(arguments), read - set(arguments)
    assert {'namespace': '', 'use_sim_time': 'false', 'use_lifecycle': 'false',
            'cmd_vel_in_topic': 'cmd_vel_nav', 'cmd_vel_out_topic': 'cmd_vel'}.items() <= (
        arguments.items())
    assert 'params_file' in arguments and "'nav2_safety_filter.yaml'" in LAUNCH_FILE.read_text()


def test_use_lifecycle_picks_one_of_two_executables():
    """``safety_filter`` unless ``use_lifecycle``, ``safety_filter_lifecycle`` if it is."""
    picks = {}
    for call in _calls('_filter_node'):
        executable, condition = call.args
        assert condition.args[0].id == 'use_lifecycle'
        picks[executable.value] = condition.func.id
    assert picks == {'safety_filter': 'UnlessCondition',
                     'safety_filter_lifecycle': 'IfCondition'}
    assert "'safety_filter = " in (REPO / 'setup.py').read_text()
    node = _calls('Node')[0]
    keywords = {k.arg for k in node.keywords}
    assert {'name', 'namespace', 'parameters', 'remappings', 'condition'} <= keywords


def test_the_params_file_names_only_node_parameters_and_builds():
    """The YAML matches the node in any namespace; every key is a parameter; it builds."""
    for namespace in ('', 'robot1'):
        values = load_parameters([PARAMS_FILE], (), namespace)
        assert values['scan_topics'] == ['scan'] and values['model'] == 'unicycle'
        settings = build_filter(values)
        assert settings.ignored == () and settings.scan_topics == ('scan',)
        assert settings.parameters['stamped'] is False  # Jazzy's Nav2 sends Twist
        # Obstacles from the scan only: no MarkerArray input and no watchdog for one.
        assert settings.use_markers is False and 'obstacles' not in settings.timeouts


def test_the_launch_file_runs_only_the_filter():
    """One of the two filter nodes and nothing else: no empty MarkerArray publisher."""
    assert len(_calls('Node')) == 1 and len(_calls('_filter_node')) == 2
    assert not _calls('ExecuteProcess') and 'empty_obstacles' not in _arguments()
