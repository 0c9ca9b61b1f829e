"""sim_bridge + nominal_controller + safety_filter as separate processes over real DDS.

Every run records a bag that is read back with ``rosbags`` (an independent
reader, deserializing from the bag's own schemas) and writes the metrics JSON.
Children inherit the per-worker ROS_DOMAIN_ID of test/conftest.py and are
always stopped.
"""
import contextlib
import json
import math
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest
from rosbags.highlevel import AnyReader

from sim_bridge.launcher import stop_processes

REPO = Path(__file__).resolve().parents[2]
# Children run from a temporary directory and import this checkout.
ENV = {**os.environ, 'PYTHONUNBUFFERED': '1', 'PYTHONPATH': os.pathsep.join(
    filter(None, [str(REPO), os.environ.get('PYTHONPATH')]))}
AT_REST = 1e-9  # m/s: braked to a stop (the body's speed, from the plant, is ~1e-15 there)
METRIC_KEYS = {'collision', 'min_clearance_m', 'goal_reached', 'time_to_goal_s',
               'path_length_m'}


def _ros_args(params, remaps=(), namespace=None, params_file=None):
    args = ['--ros-args']
    if namespace:
        args += ['-r', f'__ns:=/{namespace}']
    for remap in remaps:
        args += ['-r', remap]
    if params_file:
        args += ['--params-file', str(REPO / 'config' / params_file)]
    for name, value in params.items():
        text = str(value).lower() if isinstance(value, bool) else str(value)
        args += ['-p', f'{name}:={text}']
    return args


@contextlib.contextmanager
def processes(tmp_path, *commands):
    """Start ``(name, module, ros_args)`` children; SIGINT then SIGKILL them on exit."""
    procs = []
    try:
        for name, module, args in commands:
            log = open(tmp_path / f'{name}.log', 'w')
            procs.append(subprocess.Popen(
                [sys.executable, '-m', module, *args], cwd=tmp_path,
                env={**ENV, 'ROS_LOG_DIR': str(tmp_path / 'ros_log')},
                stdout=log, stderr=subprocess.STDOUT))
            procs[-1].log_path = tmp_path / f'{name}.log'
        yield procs
    finally:
        stop_processes(procs, timeout=10)


def controllers(robot, robot_type, goal, with_filter=True, **filter_overrides):
    """Return the nominal controller (and filter) commands for one robot namespace.

    ``filter_overrides``: more filter parameters, over its parameter file.
    """
    goal_text = '[' + ','.join(f'{g:.1f}' for g in goal) + ']'
    nominal = {'robot_type': robot_type, 'goal': goal_text}
    if not with_filter:
        remap = ['cmd_vel_in:=cmd_vel_out' if robot_type == 'quadruped'
                 else 'wrench_in:=wrench_out']
        return [('nominal', 'sim_bridge.nominal_controller_node',
                 _ros_args(nominal, remap, robot))]
    # Lockstep: one answer per stamped command, with the same-stamp odometry; the
    # steady-clock watchdogs must outlast a period on a starved machine (a stop is
    # stamped 'now', answers no period and would stall the lockstep).
    filter_params = {'trigger': 'command', 'rate': 120.0, 'match_stamps': True,
                     'odom_timeout': 10.0, 'cmd_timeout': 10.0}
    if robot_type == 'quadruped':
        filter_params['stamped'] = True
        params_file = 'quadruped.yaml'
    else:
        params_file = 'crazyflie_thrust.yaml'
    filter_params.update(filter_overrides)
    return [('nominal', 'sim_bridge.nominal_controller_node', _ros_args(nominal, (), robot)),
            ('filter', 'polyc2bf_ros.safety_filter_node',
             _ros_args(filter_params, (), robot, params_file))]


def bridge(**params):
    """Return the sim_bridge command.

    Tests wait up to 30 s (wall) for the first answers and per lockstep period by
    default: on a starved 2-core machine, three Python processes can take longer
    than the 10 s / 2 s defaults to start or answer, which would leave a robot out
    of the wait, and the tests below rely on every period being answered.
    """
    params.setdefault('startup_timeout', 30.0)
    params.setdefault('lockstep_timeout', 30.0)
    return ('bridge', 'sim_bridge.bridge_node', _ros_args(params))


def run_to_end(tmp_path, bridge_params, *others, timeout=300.0):
    """Run the bridge to the end of its scenario; return its log text.

    ``timeout`` (wall) only turns a hung run into a failure: lockstep runs take as long
    as the machine needs, so it is many times a run's length on a busy machine.
    """
    with processes(tmp_path, bridge(**bridge_params), *others) as procs:
        try:
            status = procs[0].wait(timeout=timeout)
        except subprocess.TimeoutExpired:
            pytest.fail(f'bridge still running after {timeout} s:\n'
                        + procs[0].log_path.read_text())
        log = procs[0].log_path.read_text()
        assert status == 0, log
    return log


def read_bag(path):
    """Return ``({topic: (type, count, qos profiles)}, {topic: [(log_ns, msg)]})`` via rosbags."""
    with AnyReader([Path(path)]) as reader:
        topics = {c.topic: (c.msgtype, c.msgcount, c.ext.offered_qos_profiles)
                  for c in reader.connections}
        messages = {}
        for connection, log_ns, raw in reader.messages():
            messages.setdefault(connection.topic, []).append(
                (log_ns, reader.deserialize(raw, connection.msgtype)))
    return topics, messages


def odometry(messages, topic='/a1/odom'):
    """Return the recorded odometry as (stamp ns, x, y, yaw-quaternion z, v) tuples."""
    return [(m.header.stamp.sec * 10 ** 9 + m.header.stamp.nanosec, m.pose.pose.position.x,
             m.pose.pose.position.y, m.pose.pose.orientation.z, m.twist.twist.linear.x)
            for _, m in messages[topic]]


@pytest.fixture(scope='module')
def quadruped_run(tmp_path_factory):
    """One lockstep long_wall run (3 s of sim) with nominal controller and filter."""
    tmp_path = tmp_path_factory.mktemp('quadruped')
    log = run_to_end(tmp_path, {'scenario': 'long_wall', 'duration': 3.0, 'record': True,
                                'bag_path': 'bag/run'},
                     *controllers('a1', 'quadruped', (6.0, 12.0)))
    return tmp_path, log


@pytest.mark.slow
def test_quadruped_lockstep_bag_and_metrics(quadruped_run):
    """The run ends by itself; the bag has every topic with types, counts and QoS."""
    tmp_path, log = quadruped_run
    assert 'long_wall completed at t = 3.00 s' in log
    topics, messages = read_bag(tmp_path / 'bag' / 'run')
    expected = {
        '/clock': 'rosgraph_msgs/msg/Clock', '/tf': 'tf2_msgs/msg/TFMessage',
        '/a1/odom': 'nav_msgs/msg/Odometry', '/a1/obstacles': 'visualization_msgs/msg/MarkerArray',
        '/a1/cmd_vel_in': 'geometry_msgs/msg/TwistStamped',
        '/a1/cmd_vel_out': 'geometry_msgs/msg/TwistStamped',
        '/a1/safety_filter/markers': 'visualization_msgs/msg/MarkerArray',
        '/diagnostics': 'diagnostic_msgs/msg/DiagnosticArray'}
    metrics = json.loads((tmp_path / 'bag' / 'metrics.json').read_text())
    # The filter publishes markers at 10 Hz and diagnostics at 1 Hz of wall time: a
    # lockstep run faster than that may end before the first one, and on a busy machine
    # the first one can be late.  A run 10 periods long must have one.
    wall_period = {'/a1/safety_filter/markers': 0.1, '/diagnostics': 1.0}
    for topic, type_name in expected.items():
        msgtype, count, qos = topics[topic]
        assert msgtype == type_name and qos, topic
        assert count > 0 or metrics['wall_time_s'] < 10 * wall_period.get(topic, 0.0), topic
    assert topics['/a1/obstacles'][2][0].durability.name == 'TRANSIENT_LOCAL'
    # One odom/clock/tf per 120 Hz period: the t = 0 re-sends that wait for the
    # controllers to start are published, not recorded.
    assert topics['/a1/odom'][1] == topics['/clock'][1] == topics['/tf'][1] == 3 * 120 + 1
    assert len({s for s, *_ in odometry(messages)}) == 3 * 120 + 1
    # Every period's command was answered: one safe command per stamp 0 .. t_end - T.
    stamps = [m.header.stamp.sec * 10 ** 9 + m.header.stamp.nanosec
              for _, m in messages['/a1/cmd_vel_out']]
    odom_stamps = [s for s, *_ in odometry(messages)]
    assert set(odom_stamps[:-1]) <= set(stamps)
    # ... and every period's nominal command is in the bag too (none dropped while recording).
    nominal = {m.header.stamp.sec * 10 ** 9 + m.header.stamp.nanosec
               for _, m in messages['/a1/cmd_vel_in']}
    assert set(odom_stamps[:-1]) <= nominal
    # Odometry: world frame, body child frame, sim-time stamps = log times; the robot moved.
    log_ns, first = messages['/a1/odom'][0]
    assert first.header.frame_id == 'world' and first.child_frame_id == 'a1/base_link'
    assert all(t == m.header.stamp.sec * 10 ** 9 + m.header.stamp.nanosec
               for t, m in messages['/a1/odom'])
    transform = messages['/tf'][-1][1].transforms[0]
    assert transform.header.frame_id == 'world' and transform.child_frame_id == 'a1/base_link'
    # The wall is a LINE_STRIP prism: height in scale.z, outline at z_min, world frame.
    wall = messages['/a1/obstacles'][0][1].markers[0]
    assert wall.type == 4 and wall.header.frame_id == 'world'  # LINE_STRIP
    assert math.isclose(wall.scale.z, 1.5) and wall.ns == 'obstacles'
    assert metrics['completed'] and metrics['lockstep_timeouts'] == {'a1': 0}
    assert METRIC_KEYS <= set(metrics['robots']['a1'])
    assert metrics['robots']['a1']['collision'] is False
    assert metrics['robots']['a1']['path_length_m'] > 1.0


@pytest.mark.slow
@pytest.mark.parametrize(('scenario', 'goal', 'with_filter'), [
    ('long_wall', (6.0, 12.0), False), ('long_wall', (6.0, 12.0), True),
    ('cluttered', (16.0, 0.0), True)])
def test_lockstep_runs_are_deterministic(tmp_path, scenario, goal, with_filter):
    """Two identical lockstep runs match exactly, with and without the filter in the loop.

    The filter runs with ``match_stamps``, so it answers the command of period t
    with the odometry of period t even when the command arrives first.  In
    ``cluttered`` (30 obstacles) the full marker sets, which lockstep also spaces
    in wall time, come at other periods in each run: the trajectory must not care.
    """
    runs = []
    for name in ('first', 'second'):
        (tmp_path / name).mkdir()
        run_to_end(tmp_path / name, {'scenario': scenario, 'duration': 2.0, 'record': True,
                                     'bag_path': 'bag/run'},
                   *controllers('a1', 'quadruped', goal, with_filter=with_filter))
        runs.append(odometry(read_bag(tmp_path / name / 'bag' / 'run')[1]))
    assert len(runs[0]) == len({p[0] for p in runs[0]}) == 2 * 120 + 1  # t = 0 once
    assert runs[0][-1][1] > 0.05  # it moved (the filter slows it near the wall, in clutter)
    assert runs[0] == runs[1]


@pytest.mark.slow
def test_lockstep_without_controller_brakes_and_completes(tmp_path):
    """Lockstep, nobody answers: after startup_timeout the run goes on, the robot stays put."""
    log = run_to_end(tmp_path, {'scenario': 'long_wall', 'duration': 1.0, 'record': True,
                                'bag_path': 'bag/run', 'startup_timeout': 0.3})
    assert 'no command on a1/cmd_vel_out' in log and 'completed at t = 1.00 s' in log
    poses = odometry(read_bag(tmp_path / 'bag' / 'run')[1])
    assert len({p[0] for p in poses}) == 121
    assert all(p[1:] == poses[0][1:] for p in poses)


@pytest.mark.slow
def test_popup_marker_goes_out_when_it_appears(tmp_path):
    """A pop-up at 0.55 s (between 0.2 s full sets) is in the full set sent at 0.55 s, not before.

    Before it, the full sets are empty but still sent (they feed a filter's watchdog).
    """
    scenario = {'name': 'popup_probe', 'duration': 1.0, 'physics_rate': 240,
                'control_rate': 120,
                'robots': [{'name': 'a1', 'type': 'quadruped', 'start': [0, 0, 0],
                            'goal': [5, 0]}],
                'obstacles': [{'name': 'popup', 'polygon': [[2, -1], [2.4, -1], [2.4, 1],
                                                            [2, 1]], 'appear_at': 0.55}]}
    (tmp_path / 'popup.yaml').write_text(json.dumps(scenario))  # JSON is YAML
    run_to_end(tmp_path, {'scenario': str(tmp_path / 'popup.yaml'), 'record': True,
                          'bag_path': 'bag/run', 'startup_timeout': 0.3})
    sets = [(log_ns, [(m.ns, m.id) for m in msg.markers])
            for log_ns, msg in read_bag(tmp_path / 'bag' / 'run')[1]['/a1/obstacles']]
    appear_ns = 550_000_000
    assert sets[0] == (0, [])
    assert all(markers == [] for log_ns, markers in sets if log_ns < appear_ns)
    assert (appear_ns, [('obstacles', 0)]) in sets
    # Later full sets (0.2 s of sim time and, in lockstep, 0.5 s of wall time apart) too.
    assert all(markers == [('obstacles', 0)] for log_ns, markers in sets if log_ns > appear_ns)
    metrics = json.loads((tmp_path / 'bag' / 'metrics.json').read_text())
    assert metrics['robots']['a1']['collision'] is False


@pytest.mark.slow
def test_filter_stops_before_a_popup_obstacle(tmp_path):
    """popup_obstacle with the filter in the loop: the box appears 1.75 m ahead; no collision.

    With the paper's QP cost (steering_weight 1), which brakes straight: the shipped
    weight turns round the box instead (test_in_process_loop).
    """
    run_to_end(tmp_path, {'scenario': 'popup_obstacle', 'duration': 6.0, 'record': True,
                          'bag_path': 'bag/run'},
               *controllers('a1', 'quadruped', (10.0, 0.0),
                            **{'model_params.steering_weight': 1.0}), timeout=120.0)
    poses = odometry(read_bag(tmp_path / 'bag' / 'run')[1])
    at_popup = next(p for p in poses if p[0] == 3 * 10 ** 9)
    assert at_popup[1] > 2.0 and at_popup[4] > 0.9  # driving at speed when it appears
    metrics = json.loads((tmp_path / 'bag' / 'metrics.json').read_text())
    assert metrics['robots']['a1']['collision'] is False
    assert poses[-1][1] < 4.25 - 0.35 and abs(poses[-1][4]) < 0.1  # stopped short of its face


class OdomWatcher:
    """This process's node: a command publisher and the robot's odometry speeds.

    Lets a real-time test wait for what the robot does instead of for wall time, so a
    slow machine makes it take longer, not fail.
    """

    def __init__(self, robot='a1'):
        """Create a private context, a publisher of ``robot/cmd_vel_out``, an odom listener."""
        import rclpy
        from geometry_msgs.msg import TwistStamped
        from nav_msgs.msg import Odometry
        from rclpy.executors import SingleThreadedExecutor
        from rclpy.qos import QoSProfile, ReliabilityPolicy

        self.rclpy = rclpy
        self.context = rclpy.Context()
        rclpy.init(context=self.context)
        self.node = rclpy.create_node('teleop', context=self.context)
        self.executor = SingleThreadedExecutor(context=self.context)
        self.executor.add_node(self.node)
        reliable = ReliabilityPolicy.RELIABLE
        self.publisher = self.node.create_publisher(
            TwistStamped, f'/{robot}/cmd_vel_out', QoSProfile(depth=1, reliability=reliable))
        self.command = TwistStamped()
        self.speeds = []
        self.node.create_subscription(
            Odometry, f'/{robot}/odom', lambda m: self.speeds.append(m.twist.twist.linear.x),
            QoSProfile(depth=100, reliability=reliable))

    def spin_until(self, predicate, timeout, speed=None):
        """Spin (publishing ``speed`` every 10 ms if given) until ``predicate()`` or timeout."""
        end = time.monotonic() + timeout
        while not predicate() and time.monotonic() < end:
            if speed is not None:
                self.command.twist.linear.x = speed
                self.publisher.publish(self.command)
            self.executor.spin_once(timeout_sec=0.01)
        return predicate()

    def close(self):
        """Shut the context down."""
        self.rclpy.try_shutdown(context=self.context)


@pytest.mark.slow
def test_sigint_leaves_a_readable_bag_and_metrics(tmp_path):
    """SIGINT mid-run (real-time mode): exit 0, the bag reads in rosbags, metrics written."""
    params = {'scenario': 'long_wall', 'lockstep': False, 'record': True, 'bag_path': 'bag/run'}
    watcher = OdomWatcher()
    try:
        with processes(tmp_path, bridge(**params)) as procs:
            # Mid-run: once 20 odometry messages went out, however long that takes.
            assert watcher.spin_until(lambda: len(watcher.speeds) >= 20, 60.0), \
                procs[0].log_path.read_text()
            procs[0].send_signal(signal.SIGINT)
            assert procs[0].wait(timeout=30) == 0, procs[0].log_path.read_text()
    finally:
        watcher.close()
    assert 'stopped at' in procs[0].log_path.read_text()
    topics, messages = read_bag(tmp_path / 'bag' / 'run')
    assert topics['/a1/odom'][1] > 10 and len(messages['/a1/odom']) == topics['/a1/odom'][1]
    assert (tmp_path / 'bag' / 'run' / 'metadata.yaml').is_file()
    metrics = json.loads((tmp_path / 'bag' / 'metrics.json').read_text())
    assert metrics['completed'] is False and 0 < metrics['sim_time_s'] < 30.0


@pytest.mark.slow
def test_real_time_command_timeout_brakes(tmp_path):
    """Real-time mode: a command that stops coming is dropped after command_timeout.

    Driven by what the robot does, not by wall time: 1 m/s goes out until the odometry
    shows the robot above 0.9 m/s, then nothing; once it shows it at rest, SIGINT ends
    the run.  The scenario is long enough for any machine; the bag must agree.
    """
    params = {'scenario': 'long_wall', 'lockstep': False, 'duration': 120.0,
              'command_timeout': 0.2, 'record': True, 'bag_path': 'bag/run'}
    watcher = OdomWatcher()
    try:
        with processes(tmp_path, bridge(**params)) as procs:
            log = procs[0].log_path
            assert watcher.spin_until(lambda: watcher.publisher.get_subscription_count(),
                                      60.0), log.read_text()
            assert watcher.spin_until(lambda: watcher.speeds and watcher.speeds[-1] > 0.9,
                                      60.0, speed=1.0), log.read_text()
            assert watcher.spin_until(lambda: abs(watcher.speeds[-1]) < AT_REST, 60.0), \
                log.read_text()
            procs[0].send_signal(signal.SIGINT)
            assert procs[0].wait(timeout=30) == 0, log.read_text()
    finally:
        watcher.close()
    speeds = [p[4] for p in odometry(read_bag(tmp_path / 'bag' / 'run')[1])]
    # At speed, then at rest with no command coming.  (Under load the last command can
    # still arrive after that, a reliable re-send, and nudge the robot before SIGINT.)
    at_speed = next(i for i, v in enumerate(speeds) if v > 0.9)
    assert any(abs(v) < AT_REST for v in speeds[at_speed:])


@pytest.mark.slow
def test_crazyflie_wrench_path_hovers_without_crash(tmp_path):
    """quadrotor_pillars, 2 s: nominal wrench -> filter -> bridge; it flies, does not fall."""
    params = {'scenario': 'quadrotor_pillars', 'duration': 2.0, 'record': True,
              'bag_path': 'bag/run'}
    run_to_end(tmp_path, params, *controllers('cf', 'crazyflie', (8.0, -0.2, 1.0)))
    topics, messages = read_bag(tmp_path / 'bag' / 'run')
    for topic in ('/cf/wrench_in', '/cf/wrench_out'):
        assert topics[topic][0] == 'geometry_msgs/msg/WrenchStamped' and topics[topic][1] > 200
    heights = [m.pose.pose.position.z for _, m in messages['/cf/odom']]
    assert min(heights) > 0.7 and max(heights) < 1.3
    metrics = json.loads((tmp_path / 'bag' / 'metrics.json').read_text())
    assert metrics['robots']['cf']['collision'] is False


@pytest.mark.slow
def test_parameter_service_answers_while_the_bridge_runs(tmp_path):
    """The run loop waits on its own wait set; the executor still serves ~/get_parameters."""
    import rclpy
    from rcl_interfaces.srv import GetParameters
    from rclpy.executors import SingleThreadedExecutor

    context = rclpy.Context()
    rclpy.init(context=context)
    try:
        node = rclpy.create_node('param_client', context=context)
        client = node.create_client(GetParameters, '/sim_bridge/get_parameters')
        params = {'scenario': 'long_wall', 'lockstep': False, 'duration': 20.0}
        with processes(tmp_path, bridge(**params)):
            assert client.wait_for_service(timeout_sec=30.0)
            time.sleep(1.0)  # well inside the run loop
            future = client.call_async(GetParameters.Request(names=['scenario', 'lockstep']))
            executor = SingleThreadedExecutor(context=context)
            rclpy.spin_until_future_complete(node, future, executor, timeout_sec=10.0)
            values = future.result().values
    finally:
        rclpy.try_shutdown(context=context)
    assert [values[0].string_value, values[1].bool_value] == ['long_wall', False]


def test_missing_or_unknown_scenario_is_a_clear_error(tmp_path):
    """No scenario, or an unknown one, exits 1 naming the problem."""
    for params, text in (({}, "parameter 'scenario' is required"),
                         ({'scenario': 'no_such_world'}, "no scenario named 'no_such_world'")):
        result = subprocess.run([sys.executable, '-m', 'sim_bridge.bridge_node',
                                 *_ros_args(params)], cwd=tmp_path, env=ENV, capture_output=True,
                                text=True, timeout=30)
        assert result.returncode == 1 and text in result.stderr, result.stderr
