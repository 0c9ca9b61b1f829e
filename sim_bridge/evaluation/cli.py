"""``evaluate``: the command line of every suite (scenarios, BARN, dynamic).

Usage::

    evaluate [--scenarios long_wall ...] [--filters c3bf none ...] [--seeds 0 1 2]
             [--random-seeds 3] [--duration S] [--out runs/eval] [--no-plots]
             [--obstacle-source markers|scan] [--lidar FIELD=VALUE ...]
    evaluate --suite barn [--worlds FILE] [--nominal path|goal ...] [--filters ...]
             [--jobs N] [--limit K] [--out runs/barn] [--no-plots] [--obstacle-source ...]
    evaluate --suite dynamic [--worlds 0-19 45 ...] [--difficulty easy medium hard]
             [--generator-seed SEED]
             [--nominal goal|path ...] [--filters ...] [--jobs N] [--out runs/dynamic]
             [--no-plots] [--obstacle-source ...]
    every suite also: [--latency S] [--actuator-tau S] [--odom-noise M] [-p NAME:=VALUE ...]

``--filters`` takes ``polyc2bf_paper``, ``polyc2bf_inflated``, ``c3bf``, ``none``,
``polyc2bf_footprint`` (a robot given a footprint) and ``default`` (the barrier the robot
type's shipped parameter file runs).  The
BARN suite (``sim_bridge.barn``, ``barn_suite``) runs the worlds of
``--worlds`` (default: the shipped ``bench/data/barn/barn_worlds.json``; ``--limit``:
the first K) with each nominal (default ``path``) and filter (default
``default``) over ``--jobs`` processes (default: the CPU count).  The dynamic suite
(``sim_bridge.dynamic_worlds``, ``dynamic_suite``) runs the 60 generated
worlds of moving cylinders (``--worlds``: ids and ranges; ``--difficulty``: some of
easy, medium, hard) with each nominal (default ``goal``) and filter (default
``default``), also over ``--jobs`` processes.

``--obstacle-source`` (every suite): ``markers`` (default), the ground-truth
polygons the bridge publishes, or ``scan``: each filtered robot carries the
simulated 2-D lidar of ``sim_bridge.lidar`` (``LidarSettings`` defaults: 360
beams over 360 deg, 10 m, 10 Hz, no noise, the scan plane through the base
origin; ``--lidar FIELD=VALUE`` changes one) and its filter gets only what the
node makes of the scans (``closed_loop``).  The dynamic suite's markers go through
the node's obstacle pipeline, so its filter uses estimated velocities, not the true
ones.  Every record carries ``obstacle_source`` (and ``lidar``, the settings, in scan
mode); the tables have an ``obstacles`` column.

``--latency``, ``--actuator-tau``, ``--odom-noise`` (every suite, default 0: the exact
lockstep arena): the plants act on each command that long after it is sent, follow it
to first order, and the filters get odometry with that much position noise
(``sim_bridge.actuation``).  Every record carries ``actuation`` and every table header
says it.  The scenario suite's runs and records: ``scenario_suite``.
"""
import argparse
import sys
from pathlib import Path

from polyc2bf_ros.core.decision import RESOLUTIONS
from sim_bridge.closed_loop import NOMINALS
from sim_bridge.dynamic_worlds import DEFAULT_SEED, DIFFICULTIES
from sim_bridge.evaluation.arguments import run_or_exit, run_settings
from sim_bridge.evaluation.barn_suite import main_barn
from sim_bridge.evaluation.dynamic_suite import main_dynamic
from sim_bridge.evaluation.reports import findings, markdown_table, write_outputs
from sim_bridge.evaluation.scenario_suite import DEFAULT_RANDOM_SEEDS, run_suite
from sim_bridge.launcher import FILTER_CHOICES, OBSTACLE_SOURCES, SUITE_FILTERS
from sim_bridge.lidar import PARAMETER_FIELDS as LIDAR_FIELDS
from sim_bridge.scenario import scenario_names

FILTER_NAMES = FILTER_CHOICES + ('default',)


SUITES = ('scenarios', 'barn', 'dynamic')


def _parser():
    """Return the command line parser of every suite."""
    parser = argparse.ArgumentParser(prog='evaluate', description=__doc__.split('\n')[0])
    parser.add_argument('--suite', choices=SUITES, default='scenarios',
                        help='scenarios (default): the shipped scenario files; barn: BARN worlds; '
                        'dynamic: the generated worlds of moving cylinders')
    parser.add_argument('--filters', nargs='+', default=None, choices=FILTER_NAMES,
                        metavar='FILTER', help=f'filters among {", ".join(FILTER_NAMES)} '
                        '(default: all but default for scenarios, default for barn and dynamic)')
    parser.add_argument('--out', default=None,
                        help='output directory (default runs/eval, runs/barn, runs/dynamic)')
    parser.add_argument('--no-plots', action='store_true', help='skip the PNG plots')
    parser.add_argument('--deadlock-resolution', choices=RESOLUTIONS, default=None,
                        help="the filter's deadlock_resolution (default: the parameter "
                        "file's, 'none' as shipped)")
    parser.add_argument('--obstacle-source', choices=OBSTACLE_SOURCES, default='markers',
                        help="the filters' obstacles: markers (ground truth, default) or scan "
                        '(a simulated lidar on each robot, converted as the node does)')
    parser.add_argument('--lidar', action='append', default=[], metavar='FIELD=VALUE',
                        help='with --obstacle-source scan: a lidar setting (value read as '
                        f'YAML), FIELD one of {", ".join(LIDAR_FIELDS)}; repeatable')
    parser.add_argument('--latency', type=float, default=0.0, metavar='S',
                        help='the plants act on each command this long after it is sent '
                        '(default 0: at once; sim_bridge/actuation.py)')
    parser.add_argument('--actuator-tau', type=float, default=0.0, metavar='S',
                        help="time constant of the plants' first-order velocity (rotor) "
                        'response (default 0: at once)')
    parser.add_argument('--odom-noise', type=float, default=0.0, metavar='M',
                        help="standard deviation of the noise on the filters' odometry "
                        'position, per axis (default 0: exact)')
    parser.add_argument('-p', '--param', action='append', default=[], metavar='NAME:=VALUE',
                        help='set a node parameter of every filtered robot, as ros2 run -p '
                        '(value read as YAML), e.g. -p filter.horizon:=2.0; repeatable')
    scenarios = parser.add_argument_group('scenario suite')
    scenarios.add_argument('--scenarios', nargs='+', default=None, metavar='NAME',
                           help=f'scenarios (default: all shipped: {", ".join(scenario_names())})')
    scenarios.add_argument('--seeds', nargs='+', type=int, default=None,
                           help='seeds of the scenarios with random obstacles')
    scenarios.add_argument('--random-seeds', type=int, default=None,
                           help="without --seeds: this many seeds from the scenario's own "
                           f'(default {DEFAULT_RANDOM_SEEDS})')
    scenarios.add_argument('--duration', type=float, default=None,
                           help="sim seconds per run (default: each scenario's)")
    barn = parser.add_argument_group('barn and dynamic suites')
    barn.add_argument('--worlds', nargs='+', default=None, metavar='FILE|ID',
                      help='barn: the world file (default: the shipped bench/data/barn copy); '
                      'dynamic: world ids and ranges, e.g. 0-19 45 (default: all 60)')
    barn.add_argument('--nominal', nargs='+', choices=NOMINALS, default=None,
                      help='nominal controller(s): path and/or goal (default: path for barn, '
                      'goal for dynamic)')
    barn.add_argument('--jobs', type=int, default=None,
                      help='processes (default: the CPU count)')
    barn.add_argument('--limit', type=int, default=None, metavar='K',
                      help='barn: only the first K worlds of the file')
    barn.add_argument('--robot', choices=('diff_drive', 'jackal'), default=None,
                      help="barn: the robot (default diff_drive, the 0.2 m disc; jackal: "
                      "Clearpath's box, 2 m/s, its lidar in scan mode)")
    barn.add_argument('--speed', type=float, default=None, metavar='M_S',
                      help="barn: the nominal's cruise speed [m/s] (default: the "
                      "nominal's, 1 m/s)")
    barn.add_argument('--difficulty', nargs='+', choices=list(DIFFICULTIES), default=None,
                      help='dynamic: only worlds of these difficulties (default: all)')
    barn.add_argument('--generator-seed', type=int, default=None, metavar='SEED',
                      help=f"dynamic: the world generator's seed (default {DEFAULT_SEED}, the "
                      'recorded worlds; another seed makes 60 unseen ones)')
    return parser


SUITE_OPTIONS = {'scenarios': ('scenarios', 'seeds', 'random_seeds', 'duration'),
                 'barn': ('worlds', 'nominal', 'jobs', 'limit', 'robot', 'speed'),
                 'dynamic': ('worlds', 'nominal', 'jobs', 'difficulty', 'generator_seed')}


def _misplaced_options(suite, args):
    """Return {owning suites: [given options]} for options given that ``suite`` does not take."""
    owners = {}
    for name, options in SUITE_OPTIONS.items():
        for option in options:
            owners.setdefault(option, []).append(name)
    misplaced = {}
    for option, suites in owners.items():
        if suite not in suites and getattr(args, option) is not None:
            misplaced.setdefault(' or '.join(suites), []).append(
                f'--{option.replace("_", "-")}')
    return misplaced


def main(argv=None):
    """Run the evaluation suite and write its outputs; exit 0, 2 on bad arguments, 130 on ^C."""
    parser = _parser()
    args = parser.parse_args(argv)
    for suites, given in _misplaced_options(args.suite, args).items():
        parser.error(f'{", ".join(given)} belong(s) to --suite {suites}')
    command = ('evaluate ' + ' '.join(sys.argv[1:] if argv is None else argv)).strip()
    if args.suite == 'barn':
        if args.worlds is not None:
            if len(args.worlds) != 1:
                parser.error('--suite barn takes one --worlds FILE')
            args.worlds = args.worlds[0]
        return main_barn(parser, args, command)
    if args.suite == 'dynamic':
        return main_dynamic(parser, args, command)
    scenarios = args.scenarios or scenario_names()
    unknown = [s for s in scenarios if s not in scenario_names() and not Path(s).is_file()]
    if unknown:
        parser.error(f'unknown scenario(s) {", ".join(unknown)}; shipped: '
                     f'{", ".join(scenario_names())}')
    if args.duration is not None and args.duration <= 0:
        parser.error('--duration must be > 0')
    random_seeds = DEFAULT_RANDOM_SEEDS if args.random_seeds is None else args.random_seeds
    if random_seeds < 1:
        parser.error('--random-seeds must be >= 1')
    out = args.out or 'runs/eval'
    settings = run_settings(parser, args)
    records, runs = run_or_exit(parser, run_suite, scenarios,
                                args.filters or list(SUITE_FILTERS), args.seeds, random_seeds,
                                args.duration, **settings)
    rows = write_outputs(out, records, runs, command, not args.no_plots)
    print(markdown_table(rows))
    print()
    for line in findings(records, rows):
        print(f'- {line}')
    print(f'\nwrote {Path(out) / "results.json"}, results.md'
          + ('' if args.no_plots else ', trajectories.png, metrics.png'))
    return 0
