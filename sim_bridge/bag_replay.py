"""``bag_replay``: the command line of ``bag_player`` (live) and ``bag_offline`` (offline check).

Usage::

    bag_replay BAG [--rate R] [--topics PATTERN ...] [--exclude PATTERN ...]
               [--remap FROM:=TO ...] [--clock [HZ]] [--start-offset S] [--duration S]
               [--delay S] [--wait-for-subscribers S] [--lockstep REQUEST:=RESPONSE]
               [--ros-args -r FROM:=TO ...]

    bag_replay BAG --offline [--robot NS] --params-file config/quadruped.yaml
               [-p NAME:=VALUE ...] [--json REPORT] [--tolerance TOL] [--worst N]

Exit status: 0 ok (live playback also on Ctrl-C, with its summary), 1 on bad
input (missing bag, unknown topic, invalid parameters), 2 on bad usage, 3 when
the offline check differs beyond ``--tolerance`` (or pairs nothing), 130 when
interrupted.
"""
import argparse
import json
import signal
import sys
from pathlib import Path

import rclpy
from rclpy.signals import SignalHandlerOptions

from polyc2bf_ros.filter_parameters import load_parameters, ParameterError
from sim_bridge.bag_offline import find_robot, offline_check
from sim_bridge.bag_player import BagPlayer, DEFAULT_CLOCK_HZ, log, PlayOptions, ReplayError
from sim_bridge.bag_reader import BagReader

EXIT_ERROR, EXIT_DIFFERENT, EXIT_INTERRUPTED = 1, 3, 130  # argparse: 2 on bad usage


def parse_remaps(items):
    """Return ``{from: to}`` of ``FROM:=TO`` strings (names made absolute)."""
    remaps = {}
    for item in items or ():
        source, sep, target = item.partition(':=')
        if not (sep and source and target):
            raise ReplayError(f'remap {item!r} is not FROM:=TO')
        remaps['/' + source.lstrip('/')] = '/' + target.lstrip('/')
    return remaps


def _parser():
    parser = argparse.ArgumentParser(
        prog='bag_replay', description='Play an MCAP bag onto live ROS 2 topics at its '
        'recorded timing, or (--offline) re-run the safety filter on it and compare with '
        'the recorded safe commands.', epilog='ROS arguments (--ros-args -r FROM:=TO ...) are '
        'passed to rclpy.  Exit status: 0 ok, 1 bad input, 2 bad usage, 3 offline '
        'difference beyond --tolerance.')
    parser.add_argument('bag', help='rosbag2 directory or .mcap file')
    live = parser.add_argument_group('live playback')
    live.add_argument('--rate', '-r', type=float, default=1.0,
                      help='playback speed multiplier (default 1)')
    live.add_argument('--topics', nargs='+', default=(), metavar='PATTERN',
                      help='play only these topics (names or globs)')
    live.add_argument('--exclude', nargs='+', default=(), metavar='PATTERN',
                      help='do not play these topics (names or globs)')
    live.add_argument('--remap', '-m', action='append', default=[], metavar='FROM:=TO',
                      help='publish bag topic FROM on TO (repeatable)')
    live.add_argument('--clock', nargs='?', type=float, const=DEFAULT_CLOCK_HZ, default=0.0,
                      metavar='HZ', help='publish /clock from the bag time at HZ (default '
                      f"{DEFAULT_CLOCK_HZ:g}) instead of the bag's own /clock")
    live.add_argument('--start-offset', type=float, default=0.0, metavar='S',
                      help='start S seconds into the bag')
    live.add_argument('--duration', type=float, default=0.0, metavar='S',
                      help='play S seconds of bag time (default: to the end)')
    live.add_argument('--delay', type=float, default=0.0, metavar='S',
                      help='wait S wall seconds after creating the publishers')
    live.add_argument('--wait-for-subscribers', type=float, default=0.0, metavar='S',
                      help='wait up to S seconds until every played topic has a subscriber')
    live.add_argument('--lockstep', metavar='REQUEST:=RESPONSE',
                      help='after each REQUEST message (bag topic) wait for the RESPONSE '
                      '(live topic) with the same header stamp')
    live.add_argument('--lockstep-timeout', type=float, default=10.0, metavar='S',
                      help='longest wait for one lockstep response (default 10 s)')
    live.add_argument('--quiet', '-q', action='store_true', help='no progress output')
    offline = parser.add_argument_group('offline check (no DDS)')
    offline.add_argument('--offline', action='store_true',
                         help='re-run the filter on the bag and compare')
    offline.add_argument('--robot', metavar='NS', help='robot namespace (default: the only one)')
    offline.add_argument('--params-file', action='append', default=[], metavar='YAML',
                         help="the node's parameter file (repeatable)")
    offline.add_argument('--param', '-p', action='append', default=[], metavar='NAME:=VALUE',
                         help='parameter override, as -p of --ros-args (repeatable)')
    offline.add_argument('--json', metavar='PATH', help='write the report as JSON')
    offline.add_argument('--tolerance', type=float, default=1e-6,
                         help='largest accepted |difference| (default 1e-6)')
    offline.add_argument('--worst', type=int, default=5, help='worst steps to show')
    return parser


def _run_offline(args):
    robot = args.robot or find_robot(BagReader(args.bag).topics)
    parameters = load_parameters(args.params_file, args.param, robot)
    report = offline_check(args.bag, robot, parameters, args.tolerance)
    print(report.summary(args.worst), flush=True)
    if args.json:
        Path(args.json).parent.mkdir(parents=True, exist_ok=True)
        Path(args.json).write_text(json.dumps(report.to_json(args.worst), indent=1) + '\n')
        print(f'report written to {args.json}', flush=True)
    return 0 if report.passed else EXIT_DIFFERENT


def _run_live(args, argv):
    lockstep = ()
    if args.lockstep:
        (lockstep,) = parse_remaps([args.lockstep]).items()
    options = PlayOptions(
        rate=args.rate, topics=tuple(args.topics), exclude=tuple(args.exclude),
        remaps=parse_remaps(args.remap), clock_hz=args.clock or 0.0,
        start_offset=args.start_offset, duration=args.duration, delay=args.delay,
        wait_for_subscribers=args.wait_for_subscribers, lockstep=lockstep,
        lockstep_timeout=args.lockstep_timeout, progress=not args.quiet)
    # Ctrl-C and SIGTERM raise KeyboardInterrupt in the playback loop, which ends it and
    # then shuts rclpy down; rclpy's own handlers would invalidate the context first,
    # under a publish in progress.
    signal.signal(signal.SIGTERM, _interrupt)
    rclpy.init(args=argv, signal_handler_options=SignalHandlerOptions.NO)
    player = None
    try:
        player = BagPlayer(args.bag, options)
        for source, target in player.topic_map.items():
            if source != target:
                log(f'{source} -> {target}')
        stats = player.run()
    except KeyboardInterrupt:  # before playback started
        return 0
    finally:
        if player is not None:
            player.close()
        rclpy.try_shutdown()
    print(stats.summary(), flush=True)
    return 0


def _interrupt(signum, frame):
    raise KeyboardInterrupt


def split_ros_args(argv):
    """Return ``(own arguments, ROS arguments)``: ``--ros-args ... [--]`` blocks go to ROS.

    rclpy's own splitter would also take ``NAME:=VALUE`` words outside the
    blocks (the deprecated remap syntax), which are this tool's ``-p`` values.
    """
    own, ros, inside = [], [], False
    for word in argv:
        if word == '--ros-args':
            inside = True
            ros.append(word)
        elif inside and word == '--':
            inside = False
        elif inside:
            ros.append(word)
        else:
            own.append(word)
    return own, ros


def main(argv=None):
    """Run ``bag_replay`` with ``argv`` (default ``sys.argv[1:]``); see ``--help``."""
    own, ros = split_ros_args(list(sys.argv[1:] if argv is None else argv))
    args = _parser().parse_args(own)
    try:
        if not Path(args.bag).exists():
            raise ReplayError(f'no bag at {args.bag}')
        if args.offline:
            return _run_offline(args)
        return _run_live(args, ['bag_replay', *ros])
    except (ReplayError, ParameterError, FileNotFoundError) as exc:
        log(f'error: {exc}')
        return EXIT_ERROR
    except KeyboardInterrupt:  # offline: no result to show
        log('interrupted')
        return EXIT_INTERRUPTED


if __name__ == '__main__':
    sys.exit(main())
