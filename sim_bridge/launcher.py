"""Start a scenario's closed loop as separate processes over localhost DDS, in lockstep.

``closed_loop_plan(scenario, barrier)`` says which processes a run needs:
``sim_bridge``, and per robot namespace ``<ns>`` a ``nominal_controller`` and,
unless ``barrier`` is ``'none'``, a ``safety_filter`` with the robot type's
parameter file and topics (``sim_bridge.robots``), the lockstep overrides below
and what the robot's body implies (``body_parameters``: a diff-drive disc's radius r is
``filter.robot_radius``; the filter adds the guarded point's offset l).  Without a filter the
nominal command is remapped straight onto the robot's safe-command topic.
``launch/demo.launch.py`` turns the same plan into ``launch_ros`` Node actions.

Lockstep overrides of the filter (what ``test/sim/test_bridge_closed_loop.py``
established): ``trigger: command`` with ``match_stamps: true`` (one answer per
nominal command, with the same-stamp odometry, so runs are repeatable),
``rate`` = the bridge's effective control rate (``T`` of ``v_safe = v + u T``),
steady-clock watchdogs far longer than a starved period (a watchdog stop is
stamped "now", answers no lockstep period and would stall the run), and
obstacles never stale (``obstacles_timeout: 0``: the bridge sends static
obstacles only every ``obstacles_refresh`` s of sim time, which a slow run
stretches in wall time).

With ``obstacle_source='scan'`` the filters see no ground truth: the bridge
publishes empty obstacle MarkerArrays (``obstacle_markers: false``; the filter's
obstacle watchdog still needs them) and each robot's simulated lidar on
``<ns>/scan`` (``lidar.*``: the given ``sim_bridge.lidar.LidarSettings``), and each
filter takes its obstacles from that scan (``scan_parameters``: ``scan_topics``,
``sensor_pose`` = the mount, ``scan_timeout: 0``, for the reason obstacles never go
stale in lockstep).

``run_closed_loop(...)`` starts the plan (``sys.executable -m <module>``, so a
source checkout and an install both work), each process logging to
``<run_dir>/<name>.log`` with ``ROS_LOG_DIR`` in the run directory, waits for
the bridge to finish the scenario, then stops the others with SIGINT and, after
``stop_timeout``, SIGKILL.  Every process gets ``ROS_AUTOMATIC_DISCOVERY_RANGE=
LOCALHOST`` and ``ROS_DOMAIN_ID``: the caller's, or else one picked from
``AUTO_DOMAINS`` by process id.  A process that dies before the bridge ends
stops the run (its log tail is in the result).  The bag is ``<run_dir>/run``
(a rosbag2 directory holding ``run_0.mcap``), the metrics ``<run_dir>/metrics.json``.
"""
import dataclasses
import json
import math
import os
import signal
import subprocess
import sys
import threading
import time
from pathlib import Path

from polyc2bf_ros.core.safety_filter import FilterConfig
from polyc2bf_ros.filter_parameters import load_parameters
from sim_bridge import robots
from sim_bridge.scenario import load_scenario, SCENARIO_DIR

CONFIG_DIR = SCENARIO_DIR.parent
# Children import the same code as this process: the directory holding sim_bridge/.
SOURCE_ROOT = Path(__file__).resolve().parents[1]
BARRIERS = ('polyc2bf_paper', 'polyc2bf_inflated', 'c3bf', 'polyc2bf_horizon')
SUITE_FILTERS = BARRIERS + ('none',)   # what a suite runs unless told: any robot takes them
# ``polyc2bf_footprint`` only for a unicycle robot whose parameters give a footprint.
FILTER_CHOICES = BARRIERS + ('polyc2bf_footprint', 'none')
OBSTACLE_SOURCES = ('markers', 'scan')
LOCKSTEP_FILTER = {'trigger': 'command', 'match_stamps': True, 'odom_timeout': 10.0,
                   'cmd_timeout': 10.0, 'obstacles_timeout': 0.0}
# Wall seconds the bridge waits for first answers and per period: generous for a loaded
# 2-core machine, where three Python processes per robot start and answer slowly.
LOCKSTEP_BRIDGE = {'startup_timeout': 60.0, 'lockstep_timeout': 30.0}
AUTO_DOMAINS = range(150, 230)
BAG_NAME = 'run'
METRICS_NAME = 'metrics.json'


@dataclasses.dataclass(frozen=True)
class ProcessSpec:
    """One node process: console-script ``executable``, its ``module``, ROS arguments."""

    name: str
    executable: str
    module: str
    namespace: str = ''
    parameters: dict = dataclasses.field(default_factory=dict)
    params_file: Path = None
    remappings: tuple = ()

    def ros_args(self):
        """Return the ``--ros-args ...`` list that starts this node as planned."""
        args = ['--ros-args']
        if self.namespace:
            args += ['-r', f'__ns:=/{self.namespace}']
        for remap in self.remappings:
            args += ['-r', f'{remap[0]}:={remap[1]}']
        if self.params_file is not None:
            args += ['--params-file', str(self.params_file)]
        for name, value in self.parameters.items():
            args += ['-p', f'{name}:={_parameter_text(value)}']
        return args


@dataclasses.dataclass
class RunResult:
    """What a closed-loop run left behind.

    ``status`` is the bridge's exit status (0: the scenario completed), or 1 when the
    launcher stopped the run (a node died, or the timeout passed); ``message`` says why.
    """

    status: int
    run_dir: Path
    bag_path: Path
    metrics_path: Path
    logs: dict
    domain_id: int
    wall_time_s: float
    message: str = ''

    @property
    def ok(self):
        """Return True when the bridge completed and wrote its metrics."""
        return self.status == 0 and self.metrics_path.is_file()

    @property
    def mcap_path(self):
        """Return the bag's MCAP file (``<bag>/<bag name>_0.mcap``)."""
        return self.bag_path / f'{self.bag_path.name}_0.mcap'

    def metrics(self):
        """Return the bridge's metrics JSON."""
        return json.loads(self.metrics_path.read_text())


def _parameter_text(value):
    """Return ``value`` as ``-p name:=value`` text (YAML: lists, lower-case booleans)."""
    if isinstance(value, bool):
        return str(value).lower()
    if isinstance(value, (list, tuple)):
        return '[' + ','.join(_parameter_text(v) for v in value) + ']'
    if isinstance(value, float):
        return repr(value)
    return str(value)


def control_rate(scenario):
    """Return the bridge's control rate: physics_rate / ``scenario.substeps`` (a whole number)."""
    return scenario.effective_control_rate


def params_file(robot_type):
    """Return the filter parameter file shipped for ``robot_type`` (ValueError if unknown)."""
    return CONFIG_DIR / robots.robot_type(robot_type).params_file


def default_barrier(robot_type):
    """Return the ``filter.barrier`` the shipped parameter file of ``robot_type`` runs."""
    parameters = load_parameters([params_file(robot_type)], (), '')
    return parameters.get('filter.barrier', FilterConfig.barrier)


def body_parameters(spec):
    """Return the filter overrides ``spec``'s body implies (none but for a disc body).

    ``filter.robot_radius`` is the disc's radius around the axle; the filter adds the
    model's offset_l for the guarded point (``RobotModel.guard_offset``).
    """
    if not robots.ROBOT_TYPES[spec.type].disc_body:
        return {}
    return {'filter.robot_radius': float(spec.radius)}


# sim_bridge.lidar is imported where scans are planned: it loads PyBullet, which a plan
# with markers (and the launch file) does without.

def scan_parameters(lidar):
    """Return the filter parameters that take obstacles from the robot's lidar ``lidar``.

    The scan topic, the sensor's pose in the base frame (its mount: the scan's frame is
    ``<ns>/laser``) and ``scan_timeout`` 0 (never stale once received, as lockstep needs).
    """
    from sim_bridge.lidar import SCAN_TOPIC
    return {'scan_topics': [SCAN_TOPIC], 'sensor_pose': [float(v) for v in lidar.mount],
            'scan_timeout': 0.0}


def lidar_bridge_parameters(lidar):
    """Return the bridge parameters that put ``lidar`` on every robot and drop the markers."""
    from sim_bridge.lidar import PARAMETER_FIELDS
    values = {f'lidar.{name}': getattr(lidar, name) for name in PARAMETER_FIELDS}
    values['lidar.mount'] = [float(v) for v in lidar.mount]
    return {'lidar.enabled': True, 'obstacle_markers': False, **values}


def scenario_reference(scenario):
    """Return what the bridge's ``scenario`` parameter needs: a shipped name, or an absolute path.

    The children run in the run directory, so a relative YAML path is made absolute.
    """
    path = Path(scenario)
    if path.suffix in ('.yaml', '.yml') or len(path.parts) > 1:
        return str(path.resolve())
    return str(scenario)


def closed_loop_plan(scenario, barrier='default', bridge_parameters=None,
                     filter_parameters=None, obstacle_source='markers', lidar=None):
    """Return the ProcessSpecs of one closed-loop run of ``scenario``.

    ``scenario`` is a shipped name or a YAML path, or a loaded shipped Scenario.

    ``barrier`` is a ``filter.barrier`` value, ``'default'`` (each robot's shipped
    parameter file's) or ``'none'`` (nominal command straight to the robot).
    ``bridge_parameters`` (e.g. ``duration``, ``seed``, ``record``, ``bag_path``) and
    ``filter_parameters`` override or add node parameters.
    ``obstacle_source``: 'markers' or 'scan' (module docstring; ``lidar`` defaults to
    ``LidarSettings()``).
    """
    if barrier not in FILTER_CHOICES + ('default',):
        raise ValueError(f'filter must be one of {", ".join(FILTER_CHOICES)} or default, '
                         f'got {barrier!r}')
    if obstacle_source not in OBSTACLE_SOURCES:
        raise ValueError(f'obstacle source must be one of {", ".join(OBSTACLE_SOURCES)}, '
                         f'got {obstacle_source!r}')
    sensed = {}
    if obstacle_source == 'scan':
        from sim_bridge.lidar import LidarSettings
        lidar = (lidar or LidarSettings()).validate()
        bridge_parameters = {**lidar_bridge_parameters(lidar), **(bridge_parameters or {})}
        sensed = scan_parameters(lidar)
    if hasattr(scenario, 'name'):
        reference = scenario.name  # a loaded shipped scenario
    else:
        reference = scenario_reference(scenario)
        scenario = load_scenario(reference)
    bridge = {'scenario': reference, **LOCKSTEP_BRIDGE, **(bridge_parameters or {})}
    plan = [ProcessSpec('bridge', 'sim_bridge', 'sim_bridge.bridge_node', parameters=bridge)]
    rate = control_rate(scenario)
    for robot in scenario.robots:
        robot_type = robots.ROBOT_TYPES[robot.type]
        safe, nominal = robot_type.safe_topic, robot_type.nominal_topic
        goal = [float(g) for g in robot.goal]
        controller = {'robot_type': robot.type, 'goal': goal,
                      **{f'gains.{name}': value for name, value in robot.nominal_gains.items()}}
        if barrier == 'none':
            plan.append(ProcessSpec(f'{robot.name}_nominal', 'nominal_controller',
                                    'sim_bridge.nominal_controller_node', robot.name,
                                    controller, remappings=((nominal, safe),)))
            continue
        plan.append(ProcessSpec(f'{robot.name}_nominal', 'nominal_controller',
                                'sim_bridge.nominal_controller_node', robot.name, controller))
        parameters = {**robot_type.filter_parameters, **LOCKSTEP_FILTER, 'rate': rate,
                      'filter.barrier': (default_barrier(robot.type) if barrier == 'default'
                                         else barrier), **body_parameters(robot), **sensed,
                      **(filter_parameters or {})}
        plan.append(ProcessSpec(f'{robot.name}_filter', 'safety_filter',
                                'polyc2bf_ros.safety_filter_node', robot.name, parameters,
                                params_file=CONFIG_DIR / robot_type.params_file))
    return plan


def domain_id(environ=None):
    """Return ROS_DOMAIN_ID from ``environ`` if set, else one of AUTO_DOMAINS by process id."""
    environ = os.environ if environ is None else environ
    if environ.get('ROS_DOMAIN_ID', '').strip():
        return int(environ['ROS_DOMAIN_ID'])
    return AUTO_DOMAINS[os.getpid() % len(AUTO_DOMAINS)]


def child_environment(domain, run_dir):
    """Return the children's environment: loopback DDS, ``domain``, this code on PYTHONPATH."""
    path = os.pathsep.join(filter(None, [str(SOURCE_ROOT), os.environ.get('PYTHONPATH')]))
    return {**os.environ, 'ROS_DOMAIN_ID': str(domain), 'ROS_AUTOMATIC_DISCOVERY_RANGE':
            'LOCALHOST', 'PYTHONPATH': path, 'PYTHONUNBUFFERED': '1',
            'ROS_LOG_DIR': str(Path(run_dir) / 'ros_log')}


class ClockMonitor:
    """Report the bridge's ``/clock`` (sim time [s]) to ``callback`` from a spinning thread.

    It is one more best-effort subscriber on the run's domain; rclpy is imported
    only when a monitor is made, and this process's ROS_AUTOMATIC_DISCOVERY_RANGE is
    set to LOCALHOST first, as for the children.
    """

    def __init__(self, domain, callback):
        """Create a private rclpy context and a ``/clock`` subscription on ``domain``."""
        import rclpy
        from rclpy.executors import SingleThreadedExecutor
        from rclpy.qos import QoSProfile, ReliabilityPolicy
        from rosgraph_msgs.msg import Clock

        os.environ['ROS_AUTOMATIC_DISCOVERY_RANGE'] = 'LOCALHOST'
        self._rclpy = rclpy
        self._context = rclpy.Context()
        rclpy.init(context=self._context, domain_id=domain)
        self._node = rclpy.create_node('closed_loop_progress', context=self._context,
                                       start_parameter_services=False)
        self._node.create_subscription(
            Clock, '/clock', lambda msg: callback(msg.clock.sec + 1e-9 * msg.clock.nanosec),
            QoSProfile(depth=1, reliability=ReliabilityPolicy.BEST_EFFORT))
        self._executor = SingleThreadedExecutor(context=self._context)
        self._executor.add_node(self._node)
        self._running = True
        self._thread = threading.Thread(target=self._spin, daemon=True)
        self._thread.start()

    def _spin(self):
        while self._running and self._context.ok():
            self._executor.spin_once(timeout_sec=0.1)

    def close(self):
        """Stop the thread and shut the context down."""
        self._running = False
        self._thread.join(timeout=2.0)
        self._node.destroy_node()
        self._rclpy.try_shutdown(context=self._context)


def _log_tail(path, lines=15):
    """Return the last ``lines`` lines of a log file."""
    try:
        return '\n'.join(Path(path).read_text(errors='replace').splitlines()[-lines:])
    except OSError:
        return ''


def stop_processes(procs, timeout):
    """SIGINT every process still running, wait up to ``timeout`` s, then SIGKILL."""
    for proc in procs:
        if proc.poll() is None:
            proc.send_signal(signal.SIGINT)
    deadline = time.monotonic() + timeout
    for proc in procs:
        try:
            proc.wait(timeout=max(0.0, deadline - time.monotonic()))
        except subprocess.TimeoutExpired:
            proc.kill()
            proc.wait()


def run_closed_loop(scenario, run_dir, barrier='default', duration=None, seed=None,
                    record=True, bridge_parameters=None, filter_parameters=None,
                    timeout=None, stop_timeout=10.0, progress=None, obstacle_source='markers',
                    lidar=None):
    """Run ``scenario`` in closed loop as processes; return a RunResult.

    ``scenario``, ``obstacle_source`` and ``lidar`` are as for ``closed_loop_plan``;
    ``duration`` [s of sim] and ``seed`` override the scenario's.  ``timeout`` (wall s,
    default 60 + 20 x sim duration per robot) bounds the wait for the bridge, which is
    then stopped with SIGINT (its bag is closed cleanly).  ``progress(sim_time,
    duration)``, if given, is called from a /clock subscriber thread as the run
    advances, and once with the full duration when the bridge completes the run.
    """
    reference = scenario.name if hasattr(scenario, 'name') else scenario_reference(scenario)
    scenario = load_scenario(reference)
    run_dir = Path(run_dir).resolve()
    run_dir.mkdir(parents=True, exist_ok=True)
    bag_path = run_dir / BAG_NAME
    metrics_path = run_dir / METRICS_NAME
    bridge = {'record': record, 'bag_path': str(bag_path), 'metrics_path': str(metrics_path)}
    if duration is not None:
        bridge['duration'] = float(duration)
    if seed is not None:
        bridge['seed'] = int(seed)
    bridge.update(bridge_parameters or {})
    plan = closed_loop_plan(reference, barrier, bridge, filter_parameters, obstacle_source,
                            lidar)
    sim_duration = float(bridge.get('duration', scenario.duration))
    if timeout is None:
        timeout = 60.0 + 20.0 * sim_duration * len(scenario.robots)
    domain = domain_id()
    env = child_environment(domain, run_dir)
    monitor = None
    if progress is not None:
        monitor = ClockMonitor(domain, lambda t: progress(t, sim_duration))
    logs = {spec.name: run_dir / f'{spec.name}.log' for spec in plan}
    procs, message = [], ''
    start = time.monotonic()
    try:
        # Controllers and filters first, so the bridge's first period finds them.
        for spec in plan[1:] + plan[:1]:
            with open(logs[spec.name], 'w') as log:
                proc = subprocess.Popen([sys.executable, '-m', spec.module, *spec.ros_args()],
                                        cwd=run_dir, env=env, stdout=log,
                                        stderr=subprocess.STDOUT)
            proc.spec = spec
            procs.append(proc)
        bridge_proc = procs[-1]
        deadline = start + timeout
        while bridge_proc.poll() is None:
            dead = [p for p in procs[:-1] if p.poll() is not None]
            if dead:
                spec = dead[0].spec
                message = (f'{spec.name} ({spec.executable}) exited with status '
                           f'{dead[0].returncode} before the run ended:\n'
                           + _log_tail(logs[spec.name]))
                break
            if time.monotonic() > deadline:
                message = f'the bridge did not finish within {timeout:g} s (wall); stopped'
                break
            time.sleep(0.1)
    finally:
        # The bridge first (it closes its bag), then the nodes it was talking to.
        stop_processes(procs[-1:], stop_timeout)
        stop_processes(procs[:-1], stop_timeout)
        if monitor is not None:
            monitor.close()
    # The bridge's own exit status, or 1 when the launcher had to stop the run.
    status = 1 if message or not procs else procs[-1].returncode
    if progress is not None and status == 0:
        # A run shorter than DDS discovery shows no /clock at all: end at 100 % anyway.
        progress(sim_duration, sim_duration)
    if status != 0 and not message:
        message = f'sim_bridge exited with status {status}:\n' + _log_tail(logs['bridge'])
    return RunResult(status=status, run_dir=run_dir, bag_path=bag_path,
                     metrics_path=metrics_path, logs=logs, domain_id=domain,
                     wall_time_s=time.monotonic() - start, message=message)


def format_progress(sim_time, duration, started):
    """Return ``'sim 12.3 / 30.0 s (41 %), x0.8 real time'`` since the monotonic ``started``."""
    wall = time.monotonic() - started
    share = 100.0 * min(sim_time / duration, 1.0) if duration > 0 else 100.0
    factor = sim_time / wall if wall > 0 else math.nan
    return f'sim {sim_time:5.1f} / {duration:.1f} s ({share:3.0f} %), x{factor:.2f} real time'
