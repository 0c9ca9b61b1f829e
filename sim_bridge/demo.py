"""``demo``: one scenario in closed loop over localhost DDS, then a plot and a summary.

Usage::

    demo [--scenario long_wall] [--filter default] [--duration S] [--seed N]
         [--out runs] [--obstacle-source markers|scan] [--lidar FIELD=VALUE ...]

``--filter default`` (the default) runs the barrier the first robot type's shipped
parameter file runs, as ``evaluate`` does.  Runs ``sim_bridge``, and per robot
``nominal_controller`` and ``safety_filter``,
as separate processes in lockstep (``sim_bridge.launcher``), showing sim time
as it goes.  With ``--obstacle-source scan`` the bridge publishes no obstacle
markers but each robot's simulated lidar (``<ns>/scan``, ``/tf_static``;
``--lidar FIELD=VALUE`` as for ``evaluate``), and each filter builds its obstacles
from the scans (``scan_topics``).  Everything lands in ``<out>/<timestamp>/``:

- ``run/`` the rosbag2 bag (``run_0.mcap`` + ``metadata.yaml``) and ``run.mcap``,
  a link to the MCAP file (Foxglove and ``rosbags`` open it on its own);
- ``metrics.json`` (the bridge's run metrics), ``trajectory.png``, one log per process.

The plot is drawn from the bag's odometry; the summary gives per robot the
goal, collision and minimum clearance from the metrics, and the filter's
achieved rate and step latency from the ``/diagnostics`` it published (recorded
in the bag; 1 Hz of wall time, so a run shorter than about a second has none).
Exit status 0 when the run completed, 1 when it did not, 2 on bad arguments, 130
on Ctrl-C (the processes are stopped and the bag is closed first).
"""
import argparse
import dataclasses
import math
import os
import sys
import time
from datetime import datetime
from pathlib import Path

import numpy as np

from polyc2bf_ros.filter_parameters import load_parameters
from sim_bridge import plots
from sim_bridge.bag_reader import BagReader
from sim_bridge.launcher import (
    default_barrier,
    domain_id,
    FILTER_CHOICES,
    format_progress,
    OBSTACLE_SOURCES,
    params_file,
    run_closed_loop,
)
from sim_bridge.scenario import load_scenario, scenario_names
from sim_bridge.scenario_specs import ScenarioError
from sim_bridge.world import CLEARANCE_RANGE

MCAP_LINK = 'run.mcap'
PLOT_NAME = 'trajectory.png'


def new_run_dir(out):
    """Return a fresh ``<out>/<YYYYmmdd_HHMMSS>`` (suffixed _2, _3 ... if taken)."""
    base = Path(out) / datetime.now().strftime('%Y%m%d_%H%M%S')
    path, index = base, 1
    while path.exists():
        index += 1
        path = base.with_name(f'{base.name}_{index}')
    path.mkdir(parents=True)
    return path


def read_run(bag_path, robots):
    """Return ``({robot: [(t, x, y, z)]}, {filter status name: [values dict]})`` from the bag."""
    odom_topics = {f'/{name}/odom': name for name in robots}
    paths = {name: [] for name in robots}
    diagnostics = {}
    for message in BagReader(bag_path).messages(topics=[*odom_topics, '/diagnostics']):
        msg = message.message
        if message.topic in odom_topics:
            p = msg.pose.pose.position
            stamp = msg.header.stamp.sec + 1e-9 * msg.header.stamp.nanosec
            paths[odom_topics[message.topic]].append((stamp, p.x, p.y, p.z))
            continue
        for status in msg.status:
            diagnostics.setdefault(status.name, []).append(
                {kv.key: kv.value for kv in status.values})
    return {name: np.array(rows).reshape(-1, 4) for name, rows in paths.items()}, diagnostics


def _numbers(windows, key):
    values = []
    for window in windows:
        try:
            value = float(window.get(key, 'nan'))
        except ValueError:
            continue
        if math.isfinite(value):
            values.append(value)
    return values


def filter_summary(name, windows):
    """Return one line on a filter from its diagnostics windows (1 Hz wall each).

    Rate: median over windows of the achieved rate; latency: median of the windows'
    p50 and largest of their p99 (ms); step counts by status: the last window's totals.
    """
    rates = [r for r in _numbers(windows, 'rate_achieved_hz') if r > 0]
    p50 = _numbers(windows, 'latency_p50_ms')
    p99 = _numbers(windows, 'latency_p99_ms')
    if not rates or not p50:
        return f'{name}: no filter steps in the recorded diagnostics'
    steps = {key[len('steps_'):]: value for key, value in windows[-1].items()
             if key.startswith('steps_') and value not in ('0', '')}
    counts = ', '.join(f'{key} {value}' for key, value in steps.items()) or 'none'
    return (f'{name}: {np.median(rates):.0f} commands/s (lockstep: paced by the simulation), '
            f'step latency p50 {np.median(p50):.2f} ms, p99 {max(p99):.2f} ms over '
            f'{len(windows)} diagnostics windows; steps by status until the last window: '
            f'{counts}')


def plot_run(run_dir, scenario, paths, metrics, barrier):
    """Draw the trajectory PNG; return its path."""
    first = scenario.robots[0]
    radius = float(load_parameters([params_file(first.type)], (), first.name).get(
        'filter.robot_radius', 0.0))
    collisions = []
    for name, robot in metrics['robots'].items():
        when = robot.get('collision_time_s')
        path = paths[name]
        if when is not None and len(path):
            collisions.append(path[np.argmin(np.abs(path[:, 0] - when)), 1:3])
    png = run_dir / PLOT_NAME
    plots.trajectory_figure(
        png, scenario, [paths[r.name][:, 1:] for r in scenario.robots], radius,
        f'{scenario.name}: {barrier}, {metrics["sim_time_s"]:.1f} s (lockstep over DDS)',
        labels=[f'{r.name} path' for r in scenario.robots], collisions=collisions)
    return png


def _printer(stream):
    """Return a progress callback: a line updated every 0.5 s (tty), else one per 10 %."""
    started = time.monotonic()
    last = {'wall': started, 'tenth': 0}
    tty = stream.isatty()

    def show(sim_time, duration):
        tenth = int(10.0 * sim_time / duration) if duration > 0 else 10
        if tty:
            if time.monotonic() - last['wall'] < 0.5 and sim_time < duration:
                return
            last['wall'] = time.monotonic()
        elif tenth <= last['tenth']:
            return
        last['tenth'] = tenth
        text = '  ' + format_progress(sim_time, duration, started)
        stream.write(('\r' + text) if tty else text + '\n')
        stream.flush()
    return show


def main(argv=None):
    """Run the demo; see the module docstring."""
    parser = argparse.ArgumentParser(prog='demo', description=__doc__.split('\n')[0])
    parser.add_argument('--scenario', default='long_wall',
                        help=f'shipped scenario or YAML path ({", ".join(scenario_names())})')
    parser.add_argument('--filter', default='default', choices=FILTER_CHOICES + ('default',),
                        help="barrier of the safety filter, or none; default: the robot "
                        "type's shipped one")
    parser.add_argument('--duration', type=float, default=None, help='sim seconds')
    parser.add_argument('--seed', type=int, default=None, help='random-obstacle seed')
    parser.add_argument('--out', default='runs', help='parent of the run directory (runs)')
    parser.add_argument('--obstacle-source', choices=OBSTACLE_SOURCES, default='markers',
                        help="the filters' obstacles: markers (default) or scan (lidar)")
    parser.add_argument('--lidar', action='append', default=[], metavar='FIELD=VALUE',
                        help='with --obstacle-source scan: a lidar setting, as for evaluate')
    args = parser.parse_args(argv)
    lidar = None
    if args.obstacle_source == 'scan':
        from sim_bridge.lidar import lidar_settings  # loads PyBullet: only for scans
        try:
            lidar = lidar_settings(args.lidar)
        except ValueError as exc:
            parser.error(str(exc))
    elif args.lidar:
        parser.error('--lidar needs --obstacle-source scan')
    try:
        scenario = load_scenario(args.scenario)
    except ScenarioError as exc:
        parser.error(str(exc))
    if args.duration is not None:
        if not args.duration > 0:
            parser.error('--duration must be > 0')
        scenario = dataclasses.replace(scenario, duration=args.duration)
    if args.seed is not None:
        scenario = scenario.with_seed(args.seed)
    if args.filter == 'default':
        args.filter = default_barrier(scenario.robots[0].type)
    run_dir = new_run_dir(args.out)
    robots = ', '.join(f'{r.name} ({r.type})' for r in scenario.robots)
    print(f'demo: {scenario.name} ({scenario.duration:g} s), filter {args.filter}, '
          f'obstacles from {args.obstacle_source}, robots {robots}\n'
          '  processes: sim_bridge, per robot nominal_controller'
          + (' + safety_filter' if args.filter != 'none' else '')
          + f'; lockstep over DDS on localhost, ROS_DOMAIN_ID {domain_id()}\n'
          f'  run directory: {run_dir}', flush=True)
    try:
        result = run_closed_loop(args.scenario, run_dir, barrier=args.filter,
                                 duration=scenario.duration, seed=scenario.seed,
                                 progress=_printer(sys.stderr),
                                 obstacle_source=args.obstacle_source, lidar=lidar)
    except KeyboardInterrupt:
        print(f'\ndemo: interrupted; every process stopped (a bag, if begun, closed) in {run_dir}')
        return 130
    if sys.stderr.isatty():
        sys.stderr.write('\n')
    if not result.ok:
        print(f'demo: the run failed: {result.message}\n  logs: {run_dir}/*.log', flush=True)
        return 1
    link = run_dir / MCAP_LINK
    link.symlink_to(os.path.relpath(result.mcap_path, run_dir))
    metrics = result.metrics()
    paths, diagnostics = read_run(result.bag_path, [r.name for r in scenario.robots])
    png = plot_run(run_dir, scenario, paths, metrics, args.filter)
    print(f'\nsummary ({metrics["sim_time_s"]:.1f} s simulated in {result.wall_time_s:.1f} s '
          f'wall, x{metrics["real_time_factor"] or 0:.2f} real time after start-up)')
    for name, robot in metrics['robots'].items():
        goal = (f'goal reached at {robot["time_to_goal_s"]:.1f} s' if robot['goal_reached']
                else 'goal NOT reached')
        clearance = robot['min_clearance_m']
        clearance = (f'min clearance > {CLEARANCE_RANGE:g} m' if clearance is None
                     else f'min clearance {clearance:.3f} m')
        collision = (f'COLLISION at {robot["collision_time_s"]:.2f} s' if robot['collision']
                     else 'no collision')
        print(f'  {name}: {goal}, {collision}, {clearance}, path {robot["path_length_m"]:.1f} m')
    for name in sorted(diagnostics):
        print('  ' + filter_summary(name, diagnostics[name]))
    if args.filter != 'none' and not diagnostics:
        print('  filter: no /diagnostics recorded (published once per wall second)')
    print(f'  bag:     {link} -> {os.readlink(link)} '
          f'(rosbag2 directory {result.bag_path})\n'
          f'  metrics: {result.metrics_path}\n  plot:    {png}\n  logs:    {run_dir}/*.log')
    return 0


if __name__ == '__main__':
    sys.exit(main())
