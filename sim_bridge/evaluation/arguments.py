"""The options every suite shares, turned into run settings.

``-p NAME:=VALUE`` node parameters, ``--latency`` / ``--actuator-tau`` / ``--odom-noise``
(``sim_bridge.actuation``), ``--lidar FIELD=VALUE`` (``sim_bridge.lidar``) and the
filter names (``default``: the robot type's shipped barrier); a bad value exits 2
through the parser with one line.
"""

import os
import sys

import yaml

from polyc2bf_ros.core.models import MODEL_NAMES
from polyc2bf_ros.filter_parameters import default_values, ParameterError
from sim_bridge.actuation import Actuation
from sim_bridge.launcher import default_barrier
from sim_bridge.lidar import lidar_settings
from sim_bridge.robots import ROBOT_TYPES


def override_parameters(args):
    """Return the node parameters the command line sets (``--param``, ``--deadlock-resolution``).

    Raise ValueError on a ``--param`` without ``:=``.
    """
    parameters = {}
    for item in args.param:
        name, separator, value = item.partition(':=')
        if not separator or not name:
            raise ValueError(f'--param wants NAME:=VALUE, got {item!r}')
        parameters[name] = yaml.safe_load(value)
    if args.deadlock_resolution is not None:
        parameters['deadlock_resolution'] = args.deadlock_resolution
    return parameters

def actuation_from_args(parser, args):
    """Return the Actuation of ``--latency``, ``--actuator-tau``, ``--odom-noise``; 2 if bad."""
    try:
        return Actuation(args.latency, args.actuator_tau, args.odom_noise).validate()
    except ValueError as exc:
        parser.error('--' + str(exc).replace('_', '-', 1))  # names the option

def lidar_from_args(parser, args, robot='diff_drive'):
    """Return the LidarSettings of ``--lidar`` in scan mode (None with markers); exit 2 if bad.

    ``--lidar`` fields override ``robot``'s own lidar (``RobotType.lidar``).
    """
    if args.obstacle_source != 'scan':
        if args.lidar:
            parser.error('--lidar needs --obstacle-source scan')
        return None
    try:
        return lidar_settings(args.lidar, **ROBOT_TYPES[robot].lidar)
    except ValueError as exc:
        parser.error(str(exc))


def resolve_filters(filters, robot_type):
    """Return ``filters`` with ``default`` replaced by ``robot_type``'s shipped barrier, unique."""
    return list(dict.fromkeys(default_barrier(robot_type) if name == 'default' else name
                              for name in filters))


def unknown_parameters(parameters):
    """Return the names in ``parameters`` that no model's node declares, sorted."""
    known = set().union(*(default_values(model) for model in MODEL_NAMES))
    return sorted(name for name in parameters if name not in known)


def run_settings(parser, args, robot='diff_drive'):
    """Return the settings every suite's runs take from the shared options (exit 2 if bad).

    Keys: ``parameters`` (``-p``), ``obstacle_source``, ``lidar`` (over ``robot``'s own),
    ``actuation``.  A ``-p`` name that no node declares (a typo would otherwise change
    nothing) exits 2 naming it.
    """
    try:
        parameters = override_parameters(args)
    except ValueError as exc:
        parser.error(str(exc))
    unknown = unknown_parameters(parameters)
    if unknown:
        parser.error(f'--param {unknown[0]}: the safety_filter node has no such parameter '
                     '(doc/safety_filter.md lists them)')
    return {'parameters': parameters, 'obstacle_source': args.obstacle_source,
            'lidar': lidar_from_args(parser, args, robot),
            'actuation': actuation_from_args(parser, args)}


def run_or_exit(parser, run, *arguments, **settings):
    """Return ``run(*arguments, **settings)``; a refused ``-p`` value exits 2, ^C exits 130.

    On ^C nothing is written, and the command says so.
    """
    try:
        return run(*arguments, **settings)
    except KeyboardInterrupt:
        print('\nevaluate: interrupted; nothing written', file=sys.stderr)
        raise SystemExit(130) from None
    except ParameterError as exc:  # a -p value that some robot's filter refuses
        parser.error(str(exc))


def world_suite_plan(parser, args, nominal, robot='diff_drive'):
    """Return (combos, jobs, settings) of a suite of worlds for one ground robot type.

    ``combos``: every (filter, nominal) of ``--filters`` (default ``default``: ``robot``'s)
    x ``--nominal`` (default ``nominal``); ``jobs``: ``--jobs`` or the CPU count;
    ``settings``: ``run_settings``.
    """
    filters = resolve_filters(args.filters or ['default'], robot)
    combos = [(name, chosen) for chosen in args.nominal or [nominal] for name in filters]
    return combos, args.jobs or os.cpu_count() or 1, run_settings(parser, args, robot)
