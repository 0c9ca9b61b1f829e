"""The ``safety_filter`` node's parameters: the table, and parameters -> settings, without ROS.

One home for what the node's parameters mean.  The node declares ``NODE_PARAMETERS``,
``filter.*`` (``FILTER_PARAMETERS``, one per ``FilterConfig`` field but ``control_period``,
which is ``1 / rate``) and the read-only ``model_params.*`` (``model_parameters``), and
builds everything it derives from them with ``build_settings``; offline bag replay and the
in-process evaluation build the same from the same parameter files (``load_parameters``:
rcl's YAML format, top-level keys are node name patterns (``/**`` any namespaces, ``*`` one
token) holding ``ros__parameters``; nested mappings flatten to dotted names) with
``build_filter``, the node's defaults filling in the rest.
"""
import dataclasses
import inspect
import math
import numbers
import re
from pathlib import Path

import yaml

from polyc2bf_ros.core.actuation.input_delay import braking_plan
from polyc2bf_ros.core.command_filter import CommandFilter
from polyc2bf_ros.core.decision import DEADLOCK_DEFAULTS, RESOLUTIONS, ROUTE_DEFAULTS
from polyc2bf_ros.core.geometry.polygon_limits import MAX_PARTS, MAX_VERTICES
from polyc2bf_ros.core.models import make_model, MODEL_NAMES, MODELS
from polyc2bf_ros.core.obstacles.scan_conversion import ScanSettings
from polyc2bf_ros.core.safety_filter import FilterConfig
from polyc2bf_ros.obstacle_settings import IntakeSettings, MAX_OBSTACLES

NODE_NAME = 'safety_filter'
# With ``trigger: command`` the node's timer (stale-command stops) runs at most this often.
COMMAND_WATCHDOG_PERIOD = 0.02

# name: (default, (min, max) or None, description, read-only)
NODE_PARAMETERS = {
    'model': ('unicycle', None, f'robot model, one of {", ".join(MODEL_NAMES)}', True),
    'stamped': (False, None, 'cmd_vel_in / cmd_vel_out are TwistStamped instead of Twist', True),
    'trigger': ('timer', None, "'timer': step every 1/rate s; 'command': one step per "
                'nominal command', True),
    'match_stamps': (False, None, "with trigger 'command': answer a stamped command only once "
                     'odometry stamped no earlier than it has arrived and the obstacle '
                     'messages received before it are processed (lockstep simulation, '
                     'repeatable runs); leave off when commands and odometry use different '
                     'clocks', True),
    'rate': (100.0, (1.0, 2000.0), 'control rate [Hz]: timer rate, and T = 1/rate in '
             'v_safe = v + u_safe T', False),
    'command_latency': (0.0, (0.0, 1.0), 'velocity models: the base acts on a command this '
                        'long [s] after it is published; the filter decides at the state '
                        'predicted that far ahead with the commands in flight '
                        '(core/actuation/input_delay.py)', False),
    'actuator_tau': (0.0, (0.0, 2.0), "velocity models: time constant [s] of the base's "
                     'first-order velocity loop; commands are scaled so the base realises '
                     "the filter's acceleration, and braking paths stop as slowly "
                     "(core/actuation/input_delay.py); quadrotor: its rotors' time constant, "
                     "thrust commands are scaled so the rotors reach the filter's thrusts "
                     '(core/actuation/rotor_lag.py)', False),
    'command_latency_error': (0.0, (0.0, 1.0), 'velocity models: how much longer [s] the '
                              "base's true latency may be than command_latency; the braking "
                              'check starts each stop that much later (design.md 3.13)', True),
    'actuator_tau_error': (0.0, (0.0, 2.0), "velocity models: how much slower [s] the base's "
                           'time constant may be than actuator_tau; the braking check plans '
                           'stops at the deceleration such a base realises (design.md 3.13)',
                           True),
    'velocity_tau': (0.0, (0.0, 10.0), 'tau [s] in u_nom = (v_cmd - v) / tau; 0 = one '
                     'control period (transparent when nothing constrains)', False),
    'footprint_topic': ('', None, 'geometry_msgs/PolygonStamped topic whose polygons (in the '
                        'odometry child frame) replace filter.footprint as they come, as '
                        "Nav2's collision monitor takes them; a refused one is logged and the "
                        "previous footprint kept; '': none", True),
    'odom_timeout': (0.25, (0.002, 10.0), 'odometry older than this [s] -> stop', False),
    'cmd_timeout': (0.5, (0.002, 10.0), 'nominal command older than this [s] -> stop', False),
    'use_markers': (True, None, 'subscribe to the MarkerArray topic obstacles and watch it with '
                    'obstacles_timeout; false: obstacles come from scan_topics only, which '
                    'must name one', True),
    'obstacles_timeout': (1.0, (0.0, 3600.0), 'obstacles older than this [s] -> stop; 0 = '
                          'never stale once received (latched static map)', False),
    'max_extrapolation': (0.5, (0.0, 5.0), 'obstacles are moved by velocity * age, age = '
                          'odometry stamp - obstacle stamp clipped to [0, this] [s]', False),
    'wall_thickness': (0.05, (0.001, 10.0), 'width [m] of walls from 2-point / collinear '
                       'outlines whose marker has no line width (scale.x)', False),
    'cylinder_sides': (12, (3, 64), 'sides of the polygon circumscribing CYLINDER / SPHERE '
                       'markers', False),
    'block_if_invalid': (True, None, 'rejected obstacles (wrong frame, unusable) are not fresh '
                         'data: stop once they have lasted obstacles_timeout (at once if 0)',
                         False),
    'max_vertices': (MAX_VERTICES, (3, 100000), 'outline points per polygon; more become an '
                     'enclosing convex polygon of this many vertices', False),
    'max_parts': (MAX_PARTS, (1, 10000), 'pieces per marker and convex parts per non-convex '
                  'obstacle; more: one enclosing polygon / its convex hull', False),
    'max_obstacles': (MAX_OBSTACLES, (1, 100000), 'convex obstacle parts in use; more: the '
                      'obstacle input is unusable (stop)', False),
    'stall_timeout': (0.5, (0.01, 10.0), 'no control step for this long [s] (steady clock): '
                      'a separate thread publishes the stop', False),
    'deadlock_time': (DEADLOCK_DEFAULTS[0], (0.05, 600.0), 'deadlock: the filter held the robot '
                      'against its nominal command for this long [s] ...', False),
    'deadlock_radius': (DEADLOCK_DEFAULTS[1], (0.0, 10.0), '... while its reference point '
                        'stayed within this distance [m] (core/liveness/deadlock.py); reported on '
                        '~/deadlock and in /diagnostics', False),
    'stuck_time': (DEADLOCK_DEFAULTS[2], (0.0, 3600.0), 'also a deadlock: the nominal asked '
                   'to move for this long [s] (0 = off) ...', False),
    'stuck_radius': (DEADLOCK_DEFAULTS[3], (0.0, 100.0), '... while the body stayed within '
                     'this distance [m] of where it began (circling, held and let go by turns)',
                     False),
    'deadlock_repeat_count': (DEADLOCK_DEFAULTS[4], (0, 1000), 'also a deadlock: this many '
                              'deadlock reports (0 = off) ...', False),
    'deadlock_repeat_window': (DEADLOCK_DEFAULTS[5], (0.1, 3600.0), '... within this long '
                               '[s], while the nominal still asks to move', False),
    'deadlock_resolution': ('none', None, "what a reported deadlock does: 'none' (report "
                            "only), 'circulate' (unicycle: the nominal is steered along the "
                            "blocking obstacle, core/liveness/circulation.py) or 'route' "
                            '(unicycle: along a grid route past the obstacles, '
                            'core/liveness/escape_route.py); no constraint is relaxed', False),
    'route_ahead': (ROUTE_DEFAULTS[0], (0.5, 14.0), "deadlock_resolution 'route': the route "
                    'ends this far [m] the way the nominal points', False),
    'route_window': (ROUTE_DEFAULTS[1], (2.0, 30.0), '... planned on a square grid of this '
                     'side [m] about the robot (0.1 m cells); must exceed 2 route_ahead', False),
    'route_clear_run': (ROUTE_DEFAULTS[2], (0.0, 5.0), '... and, where the window has such a '
                        'place, ends where a straight run this long [m] on that way is free '
                        '(0 = off)', False),
    'scan_timeout': (1.0, (0.0, 3600.0), 'LaserScan sources (scan_topics) older than this [s] '
                     '-> stop; 0 = never stale once received', True),
    'sensor_pose': ([0.0, 0.0, 0.0], None, '[x, y, yaw] of the laser in the odometry child '
                    'frame (base_link), for scans in any other frame that no chain of '
                    '/tf_static transforms links to it (those use the transforms, in the plane)',
                    False),
    'scan_cluster_tolerance': (0.15, (0.06, 10.0), 'largest gap [m] between neighbouring scan '
                               'endpoints of one obstacle '
                               '(core/obstacles/scan_conversion.py)', False),
    'scan_footprint_radius': (-1.0, (-1.0, 10.0), 'scan endpoints this close [m] to the base '
                              'are the robot itself; negative: filter.robot_radius (with '
                              "filter.footprint: its covering disc's radius; guarded as a "
                              'polygon: the disc inside it, less 3 cm)', False),
    'scan_obstacle_depth': (0.10, (0.02, 10.0), 'how far [m] each scan obstacle reaches behind '
                            'the surface the beams lit (the unseen body behind it)', False),
    'scan_split_tolerance': (0.05, (0.001, 10.0), 'largest distance [m] of a scan endpoint '
                             'from the side of its obstacle: smaller outlines curved surfaces '
                             'closer, with more polygons; at most scan_cluster_tolerance less '
                             '0.01 m (core/obstacles/scan_conversion.py, step 4)', False),
    'scan_tracking': (True, None, 'track scan clusters from scan to scan '
                      '(core/obstacles/scan_tracker.py): obstacles of a confirmed, moving '
                      'track get its velocity; false: every scan obstacle stands still', False),
    'scan_unknown_speed': (2.0, (0.0, 10.0), 'bound [m/s] on the speed of a scan obstacle whose '
                           'track is not trusted (once moving, then not registered or '
                           'holding two objects; core/obstacles/scan_tracker.py); the braking '
                           'check allows for it; 0 = off', False),
    'scan_hidden_speed': (1.0, (0.0, 10.0), 'bound [m/s] on the speed of what a moving scan '
                          'track may hide behind or inside its cluster: its obstacles (and '
                          'its predicted outline while a scan misses it) get it as unknown '
                          'velocity, which the braking check allows for and no evasion '
                          'commits past; 0 = off (a moving track is taken at its '
                          'velocity)', False),
    'scan_memory_time': (10.0, (0.0, 3600.0), 'a laser with a blind sector: endpoints it saw '
                         'are kept while no beam can see them, and once farther than '
                         'scan_memory_range for this long [s] at most '
                         '(core/obstacles/scan_memory.py), so a turning or backing body '
                         'knows what passed behind it; 0 = off',
                         False),
    'scan_memory_range': (1.5, (0.01, 30.0), '... and drawn while this close [m] to the sensor',
                          False),
    'odom_position_std': (0.0, (0.0, 1.0), 'noise [m] of the odometry position scans are '
                          'placed at; the scan tracker allows for it in every displacement it '
                          'measures, so a standing object is not taken for a moving one', False),
    'odom_heading_std': (0.0, (0.0, 0.5), 'noise [rad] of the odometry heading scans are '
                         'placed at (as odom_position_std, times the range)', False),
}

# FilterConfig field: ((min, max) or None, description); control_period comes from rate.
FILTER_PARAMETERS = {
    'barrier': (None, "cone construction: 'polyc2bf_paper' (segment extended by w/2), "
                "'polyc2bf_inflated' (polygon inflated by the radius), 'c3bf' (circles) or "
                "'polyc2bf_horizon' (inflated, only what is reachable within the horizon) or "
                "'polyc2bf_footprint' (the footprint polygon turning with the unicycle, "
                'horizon as polyc2bf_horizon)'),
    'robot_radius': ((0.0, 10.0), 'robot radius w/2 [m]'),
    'footprint': (None, 'the body as a polygon "[[x, y], ...]" [m] in the odometry child '
                  "frame (Nav2's footprint); '[]': the disc of robot_radius.  Set, it "
                  'replaces robot_radius: the disc about the origin covering it is guarded, '
                  'or with barrier polyc2bf_footprint the polygon itself'),
    'gamma': ((0.0, 1000.0), 'class-K gain in h_dot + gamma h >= margin [1/s], > 0'),
    'margin_gain': ((0.0, 1000.0), 'sample-and-hold margin = margin_gain * T'),
    'solver': (None, "QP solver: 'daqp' or 'proxsuite'"),
    'velocity_epsilon': ((0.0, 10.0), 'smooth norm sqrt(|v_rel|^2 + eps^2) [m/s], > 0'),
    'slack_weight': ((0.0, 1e12), 'weight of the shared slack when the QP is infeasible, > 0'),
    'prune': (None, 'drop rows that no input in the box can violate (same solution)'),
    'escape_speed': ((0.0, 10.0), 'speed [m/s] of the escape from inside an obstacle'),
    'escape_gain': ((0.0, 1000.0), 'gain [1/s] of the escape velocity loop, > 0'),
    'inflation_segments': ((3, 256), 'segments of the robot disc for polyc2bf_inflated'),
    'horizon': ((0.0, 1e9), 'polyc2bf_horizon: time horizon tau [s]; a closing velocity '
                'is allowed while contact is more than tau away, > 0'),
    'cone_axis': (None, "polyc2bf_horizon: cone axis 'bisector' (the exact silhouette) or "
                  "'midpoint' (the paper's)"),
    'braking_check': (None, 'planar models: keep an input only if the robot can still brake '
                      'to rest clear of every obstacle afterwards, else brake now '
                      '(core/barrier/braking_check.py)'),
    'braking_check_barrier': (None, 'braking check: also keep every barrier h >= 0 along the '
                              'way to rest (polyc2bf_horizon), else brake now'),
    'braking_margin': ((0.0, 1.0), 'braking check: clearance kept beyond robot_radius [m]'),
    'braking_obstacle_accel': ((0.0, 100.0), 'braking check: bound [m/s^2] on how fast a '
                               'moving obstacle changes velocity on the way to rest; a '
                               'point t s ahead loses a t^2 / 2 of its clearance to it'),
    'obstacle_accel': ((0.0, 100.0), 'planar models: bound [m/s^2] on how fast a moving '
                       'obstacle changes velocity; its rows hold for any such change (0: none)'),
    'obstacle_velocity_error': ((0.0, 10.0), 'planar models: bound [m/s] on the error of a '
                                "moving obstacle's estimated velocity; its rows hold for any "
                                'such error (0: velocities are exact)'),
    'evasion_horizon': ((0.0, 10.0), 'planar models with the braking check: look ahead [s] '
                        'over which a moving obstacle must not reach the robot; when one '
                        'would, hold the input that keeps clearest instead (0: never evade)'),
    'evasion_commit': (None, 'evasion: also take an input whose look ahead keeps clear of '
                       'every obstacle all along, checked against standing obstacles only '
                       '(faster past crossing obstacles; trusts their estimated velocities, '
                       'so never while an untrusted scan track is near)'),
    'evasion_max_speed': ((0.0, 100.0), 'evasion: the fastest [m/s] a look ahead taken may '
                          'drive the robot, or its speed now if faster; a lagging base stops '
                          'later than planned, sooner from a slower evasion (0: no limit)'),
    'max_reverse_speed': ((0.0, 100.0), 'unicycle: the fastest [m/s] the filter backs the '
                          'robot, or as fast as the nominal asks if faster; a laser facing '
                          'forward does not see where the robot backs (0: no limit)'),
    'ground_z': (None, '3-D models: height of the ground [m], an obstacle like any other '
                 '(core/obstacles/ground.py); -.inf: no ground'),
}

class ParameterError(ValueError):
    """An unreadable parameter file or an invalid parameter value, with the reason."""


def _node_pattern(key):
    """Regex of an rcl parameter-file node key (``/**`` any namespaces, ``*`` one token)."""
    key = '/' + key.lstrip('/')
    parts = []
    for token in key.split('/')[1:]:
        if token == '**':
            parts.append('(?:/[^/]+)*')
        else:
            parts.append('/' + re.escape(token).replace(r'\*', '[^/]*'))
    return re.compile(''.join(parts) + '$')


def _flatten(values, prefix=''):
    flat = {}
    for key, value in values.items():
        if isinstance(value, dict):
            flat.update(_flatten(value, f'{prefix}{key}.'))
        else:
            flat[f'{prefix}{key}'] = value
    return flat


def load_parameters(params_files, overrides, namespace):
    """Return ``{name: value}`` for node ``/namespace/safety_filter`` from rcl YAML files.

    Every section whose node pattern matches is applied in file order; then
    the ``NAME:=VALUE`` ``overrides`` (values parsed as YAML, like ``-p``).
    """
    fqn = f'/{namespace.strip("/")}/{NODE_NAME}' if namespace.strip('/') else f'/{NODE_NAME}'
    values = {}
    for path in params_files or ():
        try:
            data = yaml.safe_load(Path(path).read_text()) or {}
        except OSError as exc:
            raise ParameterError(f'cannot read parameter file {path}: {exc.strerror}') from None
        except yaml.YAMLError as exc:
            raise ParameterError(f'parameter file {path} is not YAML: {exc}') from None
        for key, section in data.items():
            if not isinstance(section, dict) or 'ros__parameters' not in section:
                raise ParameterError(f'{path}: section {key!r} has no ros__parameters')
            if _node_pattern(str(key)).match(fqn):
                values.update(_flatten(section['ros__parameters'] or {}))
    for item in overrides or ():
        name, sep, text = item.partition(':=')
        if not (sep and name):
            raise ParameterError(f'parameter {item!r} is not NAME:=VALUE')
        values[name] = yaml.safe_load(text)
    return values


def model_parameters(model_name):
    """Return ``{name: default}`` of the numeric constructor arguments of a model."""
    signature = inspect.signature(MODELS[model_name].__init__)
    return {name: float(p.default) for name, p in signature.parameters.items()
            if isinstance(p.default, (float, int)) and not isinstance(p.default, bool)}


FILTER_FIELDS = tuple(f.name for f in dataclasses.fields(FilterConfig)
                      if f.name != 'control_period')


@dataclasses.dataclass
class NodeSettings:
    """Everything the node derives from its parameters, built and validated together.

    ``timeouts``: the watchdogs', ``obstacles`` only with ``use_markers``; the node's
    ``watchdog_timeouts`` add one per scan topic (``scan_topics``, deduplicated, each
    ``scan_timeout``, named by ``scan_watchdog``); ``parameters`` is
    every value used (defaults filled in); ``ignored`` the names given that the node does not
    declare (callers report them).
    """

    command_filter: CommandFilter
    model_name: str
    period: float
    per_command: bool
    timeouts: dict
    use_markers: bool
    intake: IntakeSettings
    stall_timeout: float
    block_if_invalid: bool
    max_extrapolation: float
    deadlock: tuple
    resolution: str
    route: tuple
    parameters: dict
    scan_topics: tuple = ()
    scan_timeout: float = 0.0
    ignored: tuple = ()

    @property
    def tick(self):
        """Return the period of the node's timer: the step, or the stale-command check."""
        return max(self.period, COMMAND_WATCHDOG_PERIOD) if self.per_command else self.period

    @property
    def scan_watchdogs(self):
        """Return ``{scan topic: the name of its watchdog}``."""
        return {topic: scan_watchdog(topic) for topic in self.scan_topics}

    @property
    def watchdog_timeouts(self):
        """Return the node's watchdog timeouts: ``timeouts`` and one per scan topic."""
        return {**self.timeouts,
                **dict.fromkeys(self.scan_watchdogs.values(), self.scan_timeout)}


def scan_watchdog(topic):
    """Return the watchdog name of the scan topic ``topic`` (``scan_`` + its path)."""
    return 'scan_' + topic.strip('/').replace('/', '_')


def _filter_values(values):
    """Return what ``build_settings`` builds the ``CommandFilter`` from, besides the model."""
    return ([values[name] for name in ('rate', 'velocity_tau', 'command_latency', 'actuator_tau')]
            + [values[f'filter.{name}'] for name in FILTER_FIELDS])


def build_settings(values, model=None, reuse=None):
    """Return ``NodeSettings`` from ``{name: value}``; ``ParameterError`` names what is wrong.

    ``values`` holds every node parameter (``model_params.*`` and ``filter.*`` included);
    ``model`` reuses an already built model instead of building one from ``model_params``.
    ``reuse``: settings built before with that ``model``; their filter is taken when
    ``values`` would build the same one, so checking a change of anything else builds none.
    """
    model_name = values['model']
    if model_name not in MODELS:
        raise ParameterError(f"parameter 'model' must be one of {MODEL_NAMES}, "
                             f'got {model_name!r}')
    if values['trigger'] not in ('timer', 'command'):
        raise ParameterError("parameter 'trigger' must be 'timer' or 'command', "
                             f"got {values['trigger']!r}")
    for name in ('command_latency', 'actuator_tau', 'command_latency_error',
                 'actuator_tau_error'):
        value = values[name]
        if (isinstance(value, bool) or not isinstance(value, numbers.Real)
                or not math.isfinite(value) or value < 0.0):
            raise ParameterError(f'invalid filter parameters: {name} must be a finite '
                                 f'number >= 0, got {value!r}')
    try:
        rate = float(values['rate'])
        if not rate > 0.0:
            raise ValueError(f'rate must be positive, got {rate}')
        period = 1.0 / rate
        if model is None:
            arguments = {name: values.get(f'model_params.{name}', default)
                         for name, default in model_parameters(model_name).items()}
            tau, tau_error = float(values['actuator_tau']), float(values['actuator_tau_error'])
            if 'brake_time_constant' in arguments:  # a lagging base brakes as slowly
                arguments['brake_time_constant'] = max(arguments['brake_time_constant'],
                                                       tau + tau_error)
            model = make_model(model_name, **arguments).plan_braking(*braking_plan(
                period, tau, tau_error, float(values['command_latency_error'])))
        config = FilterConfig(control_period=period, **{
            name: values[f'filter.{name}'] for name in FILTER_FIELDS}).validate()
        if reuse is not None and _filter_values(reuse.parameters) == _filter_values(values):
            command_filter = reuse.command_filter
        else:
            command_filter = CommandFilter(model, config, float(values['velocity_tau']),
                                           float(values['command_latency']),
                                           float(values['actuator_tau']))
    except (TypeError, ValueError) as exc:
        raise ParameterError(f'invalid filter parameters: {exc}') from None
    use_markers = bool(values['use_markers'])
    scan_topics = tuple(dict.fromkeys(topic for topic in values.get('scan_topics') or ()
                                      if topic))
    if not (scan_topics or use_markers):
        raise ParameterError('use_markers is false and scan_topics is empty: the node has no '
                             'obstacle source (set scan_topics, or use_markers true)')
    watched = ('odom', 'cmd', 'obstacles') if use_markers else ('odom', 'cmd')
    timeouts = {name: float(values[f'{name}_timeout']) for name in watched}
    for name, timeout in timeouts.items():
        if 0.0 < timeout <= period:
            raise ParameterError(f'{name}_timeout ({timeout:g} s) must exceed the control '
                                 f'period 1/rate ({period:g} s)')
    try:  # the scan settings' own check: split tolerance and cluster tolerance together
        ScanSettings(cluster_tolerance=float(values['scan_cluster_tolerance']),
                     depth=float(values['scan_obstacle_depth']),
                     split_tolerance=float(values['scan_split_tolerance']))
    except ValueError as exc:
        raise ParameterError('invalid scan parameters (scan_split_tolerance, '
                             f'scan_cluster_tolerance, scan_obstacle_depth): {exc}') from None
    scan_timeout = float(values['scan_timeout'])
    if scan_topics and 0.0 < scan_timeout <= period:
        raise ParameterError(f'scan_timeout ({scan_timeout:g} s) must exceed the control '
                             f'period 1/rate ({period:g} s), or be 0')
    latency, command_timeout = float(values['command_latency']), float(values['cmd_timeout'])
    if latency >= command_timeout:
        raise ParameterError(f'command_latency ({latency:g} s) must be below cmd_timeout '
                             f'({command_timeout:g} s): the stop for a stale command would '
                             'reach the base only after the command it stops had timed out')
    settings = NodeSettings(
        command_filter=command_filter, model_name=model_name, period=period,
        per_command=values['trigger'] == 'command', timeouts=timeouts, use_markers=use_markers,
        intake=IntakeSettings(*(values[name] for name in IntakeSettings._fields)),
        stall_timeout=float(values['stall_timeout']),
        block_if_invalid=bool(values['block_if_invalid']),
        max_extrapolation=float(values['max_extrapolation']),
        deadlock=tuple(float(values[name]) for name in (
            'deadlock_time', 'deadlock_radius', 'stuck_time', 'stuck_radius',
            'deadlock_repeat_count', 'deadlock_repeat_window')),
        resolution=values['deadlock_resolution'],
        route=(float(values['route_ahead']), float(values['route_window']),
               float(values['route_clear_run'])),
        parameters=dict(values), scan_topics=scan_topics, scan_timeout=scan_timeout)
    if settings.resolution not in RESOLUTIONS:
        raise ParameterError(f"parameter 'deadlock_resolution' must be one of {RESOLUTIONS}, "
                             f'got {settings.resolution!r}')
    ahead, window, _ = settings.route
    if not window > 2.0 * ahead:
        raise ParameterError(f'route_window ({window:g} m) must exceed 2 route_ahead '
                             f'({2.0 * ahead:g} m): the route ends inside the window')
    if not settings.stall_timeout > 2.0 * settings.tick:
        raise ParameterError(f'stall_timeout ({settings.stall_timeout:g} s) must exceed two '
                             f'control ticks ({2.0 * settings.tick:g} s)')
    return settings


def default_values(model_name):
    """Return ``{name: default}`` of every parameter the node declares for ``model_name``."""
    values = {name: spec[0] for name, spec in NODE_PARAMETERS.items()}
    values['model'] = model_name
    values['scan_topics'] = []  # declared apart by the node: a string array with no default
    values.update({f'model_params.{name}': default
                   for name, default in model_parameters(model_name).items()})
    defaults = FilterConfig()
    values.update({f'filter.{name}': getattr(defaults, name) for name in FILTER_FIELDS})
    return values


def build_filter(parameters):
    """Return ``NodeSettings`` as the node builds them from ``parameters`` (defaults for the rest).

    Unknown names end up in ``ignored``.
    """
    model_name = parameters.get('model', NODE_PARAMETERS['model'][0])
    if model_name not in MODELS:
        raise ParameterError(f"parameter 'model' must be one of {MODEL_NAMES}, "
                             f'got {model_name!r}')
    values = default_values(model_name)
    unknown = sorted(name for name in parameters if name not in values)
    values.update({name: value for name, value in parameters.items() if name in values})
    settings = build_settings(values)
    settings.ignored = tuple(unknown)
    return settings
