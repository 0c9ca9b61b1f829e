"""Benchmark one SafetyFilter.step: p50/p99/max latency vs obstacle count, backend, barrier.

Usage: python bench/bench_core.py [--steps N] [--repeats R] [--out bench/results/core.json]
       [--models unicycle ...] [--backends daqp ...] [--counts 1 10 ...]
       [--barrier NAME ...] [--in-reach] [--rate HZ] [--no-startup] [--rebuilds N]
       [--moving M]

Every step of a closed-loop numpy rollout is timed: the robot starts at rest
and its nominal controller drives it towards a goal 15 m away (40 m in_reach),
so the mix of ok / slack steps is the one the filter meets in operation.  The filter
runs at ``--rate`` (default 100 Hz, the control period of ``FilterConfig``), and the
rollout lasts 20 s (``--steps`` periods: 2000 at 100 Hz, 20000 at 1 kHz).  The obstacle set
is built once per case, as the node does once per obstacle message.  Layouts:

* ``scattered`` (the default): N random 8-gons 2-20 m around the start, drifting
  at up to 0.1 m/s; out of the braking check's reach on part of the steps.
* ``in_reach`` (``--in-reach``, default N = 50): N static 8-gons along the way,
  one just behind the start and the others in two staggered rows flanking it
  (near edges 0.95-1.05 m off it, over -0.5..21 m; the goal at 40 m, so that the
  robot drives between them for 2000 steps at up to 1 m/s).  Some obstacle's box is
  then within the braking check's reach (``RobotModel.braking_reach``) of the
  robot on every step, and the check runs where its quick box test would skip it.

Filter configurations (``--barrier NAME``, repeatable; default: ``default``):
``default`` is the node's default filter (``FilterConfig()``: the horizon barrier
with the braking check, what ``filter_parameters.build_filter`` gives without
overrides); ``footprint`` the ``polyc2bf_footprint`` barrier guarding a 0.508 x 0.430 m
box footprint turning with the unicycle instead of the 0.3 m disc; ``eq7`` the paper's
eq. 7, configured as ``bench_node.py``'s ``command_eq7`` (``polyc2bf_inflated``, midpoint
axis, no braking check); a ``filter.barrier`` value (the rest at its default, the braking
check on); or such a value with ``:no_braking`` (the braking check off).  ``eq7`` is always
measured too: the configurations of a case step interleaved (each its own
rollout, the order rotating every step), and each row gives its p50 and p99 as
ratios to eq. 7's of the same repeat.  ``check`` is the share of steps on which
the braking check ran past its box test, ``paths`` the share on which it computed the
braking paths (its stop bands did not certify the input), ``evade`` the share on which
the evasion looked ahead (a moving part near); all from the filter's own tests
(``_far_from_all``, ``_stop_certified``, ``_moving_near``), asked again after the timed
step, since the filter keeps no count.  Each case runs ``--repeats`` times; p50, p99 and the
ratios are the medians over the repeats, max the largest.

Rebuild (``core_rebuild``): every new obstacle set (each obstacle message;
each step while obstacles move) is built with ``ObstacleSet.from_obstacles``
and prepared by the filter (``SafetyFilter.prepare``: inflation, circles,
vertical views).  Per model and barrier, a set of N convex 8-gons of which
``--moving`` translate every period is rebuilt ``--rebuilds`` times; both parts
are timed.  Beside it (``moved`` columns) the same motion as a translation of
the first set (``ObstacleSet.translated`` + ``prepare``, which reuses the
first set's prepared geometry): what pose-only updates cost.

Start-up: fresh processes time the import and the construction of a filter
for every model and barrier, and report their RSS: with the kernels built
ahead of time (``polyc2bf_ros.core.kernels.jit``), then just in time by numba with an
empty cache directory (compiling) and with the cache that run filled.
"""
import argparse
import json
import os
import subprocess
import sys
import tempfile
import time

import numpy as np
from bench_io import require_installed_checkout, write_records

from polyc2bf_ros.core.geometry.polygons import convex_hull
from polyc2bf_ros.core.kernels import jit
from polyc2bf_ros.core.models import make_model
from polyc2bf_ros.core.obstacles.obstacle_set import Obstacle, ObstacleSet
from polyc2bf_ros.core.safety_filter import CONE_MODELS, FilterConfig, FilterStatus, SafetyFilter
from sim_bridge.nominal import QuadrotorGoalController, UnicycleGoalController
from sim_bridge.rollout import rk4_step

OBSTACLE_COUNTS = (1, 10, 50, 200)
VERTICES = 8
BACKENDS = ('daqp', 'proxsuite')
MODELS = ('unicycle', 'quadrotor')
# What this process steps with: the built extension, or numba's just-in-time kernels (the
# build's digest differs from the imported sources, or no build).
KERNELS = 'ahead_of_time' if jit.AHEAD_OF_TIME is not None else 'just_in_time'


def octagon_obstacles(count, rng):
    """Return ``count`` obstacles: convex 8-gons scattered 2-20 m around the origin."""
    angles = np.linspace(0.0, 2.0 * np.pi, VERTICES, endpoint=False)
    obstacles = []
    for _ in range(count):
        distance, bearing = rng.uniform(2.0, 20.0), rng.uniform(-np.pi, np.pi)
        centre = distance * np.array([np.cos(bearing), np.sin(bearing)])
        radii = rng.uniform(0.2, 0.6) * rng.uniform(0.8, 1.0, VERTICES)
        polygon = convex_hull(centre + np.column_stack([radii * np.cos(angles),
                                                        radii * np.sin(angles)]))
        obstacles.append(Obstacle(polygon=polygon, velocity=rng.uniform(-0.1, 0.1, 3),
                                  z_min=0.0, z_max=rng.uniform(0.5, 3.0)))
    return obstacles


def octagons(count, rng):
    """Return the ObstacleSet of ``octagon_obstacles``."""
    return ObstacleSet.from_obstacles(octagon_obstacles(count, rng))


CORRIDOR = (-0.5, 21.0)  # in_reach: x range of the two rows of 8-gons [m]
IN_REACH_GOAL_X = 40.0  # in_reach: the goal, beyond the rows: the robot drives on [m]
CORRIDOR_EDGE = (0.95, 1.05)  # in_reach: their near edges' distance from the x axis [m]
CAP_EDGE = -0.65  # in_reach: the near edge of the 8-gon behind the start [m]


def _octagon(rng):
    """Return a random convex 8-gon of radius 0.2-0.3 m about the origin."""
    angles = np.linspace(0.0, 2.0 * np.pi, VERTICES, endpoint=False)
    radii = rng.uniform(0.2, 0.3) * rng.uniform(0.8, 1.0, VERTICES)
    return convex_hull(np.column_stack([radii * np.cos(angles), radii * np.sin(angles)]))


def in_reach_obstacles(count, rng):
    """Return ``count`` static 8-gons along the way to the goal (``in_reach``).

    One behind the start, its near edge 0.65 m behind the robot (in the braking check's
    reach of a unicycle at rest: rho + the guard radius + the margin = 0.71 m); the
    others in two staggered rows flanking the x axis up to 21 m, near edges 0.95-1.05 m
    off it (in reach from about 0.5 m/s: 1.68 m at 1 m/s; a 2 m corridor that eq. 7 also
    drives through).  The goal lies beyond, at 40 m: at up to 1 m/s the robot is still
    between the rows after 2000 steps.  1.5-3 m tall: in a quadrotor's way at 1 m.
    Static: the evasion, which looks ahead only near moving parts, stays off (the
    scattered layout's parts drift).
    """
    polygon = _octagon(rng)
    polygons = [polygon + [CAP_EDGE - polygon[:, 0].max(), 0.0]]
    rest = count - 1
    for side, n in ((1.0, (rest + 1) // 2), (-1.0, rest // 2)):
        spacing = (CORRIDOR[1] - CORRIDOR[0]) / max(n, 1)
        offset = (0.25 if side > 0 else 0.75) * spacing  # staggered rows
        for k in range(n):
            polygon = _octagon(rng)
            edge = rng.uniform(*CORRIDOR_EDGE)
            shift_y = edge - polygon[:, 1].min() if side > 0 else -edge - polygon[:, 1].max()
            polygons.append(polygon + [CORRIDOR[0] + offset + k * spacing, shift_y])
    return [Obstacle(polygon=p, velocity=np.zeros(3), z_min=0.0, z_max=rng.uniform(1.5, 3.0))
            for p in polygons[:count]]


LAYOUTS = {'scattered': octagon_obstacles, 'in_reach': in_reach_obstacles}

RATE = 100.0  # default control rate [Hz]: FilterConfig's control period, CASES' period
ROLLOUT_S = 20.0  # default length of a timed rollout [s]
CASES = {
    # model: (start state, goal, controller, control period, physics substeps)
    'unicycle': (np.zeros(5), np.array([15.0, 0.0]), UnicycleGoalController(), 0.01, 1),
    'quadrotor': (np.array([0, 0, 1.0] + [0.0] * 9), np.array([15.0, 0.0, 1.0]),
                  QuadrotorGoalController(), 0.01, 5),
}

DEFAULT, EQ7, NO_BRAKING = 'default', 'eq7', ':no_braking'
FOOTPRINT = 'footprint'
# Filter configurations by name: FilterConfig fields over its defaults.  eq7 is
# bench_node.py's command_eq7 (FILTER_SUBJECTS): eq. 7 on inflated polygons, midpoint axis,
# no braking check; footprint the Jackal's 4-vertex box turning with the unicycle
# (``barrier.footprint_cone``).
CONFIGURATIONS = {
    DEFAULT: {},
    FOOTPRINT: {'barrier': 'polyc2bf_footprint',
                'footprint': '[[0.254, 0.215], [-0.254, 0.215], [-0.254, -0.215], '
                             '[0.254, -0.215]]'},
    EQ7: {'barrier': 'polyc2bf_inflated', 'cone_axis': 'midpoint', 'braking_check': False},
    **{name: {'barrier': name} for name in CONE_MODELS},
    **{name + NO_BRAKING: {'barrier': name, 'braking_check': False} for name in CONE_MODELS},
}
# Statuses after which the braking check may have run (it runs on the first four).
CHECKED = frozenset(s.value for s in (FilterStatus.OK, FilterStatus.RECOVERING,
                                      FilterStatus.SLACK, FilterStatus.ESCAPE,
                                      FilterStatus.BACKUP, FilterStatus.EVADE))


def configurations(names):
    """Return the configuration names to time: ``names`` (default: default) and eq7, once each.

    Exits with one line listing the choices on an unknown name.
    """
    unknown = [name for name in names or () if name not in CONFIGURATIONS]
    if unknown:
        sys.exit(f'bench_core.py: unknown --barrier {unknown[0]!r}; choose from '
                 f'{", ".join(CONFIGURATIONS)}')
    return list(dict.fromkeys([*(names or [DEFAULT]), EQ7]))


def make_filter(model_name, backend, period, configuration):
    """Return a SafetyFilter of ``configuration`` (robot radius 0.3 m, ``backend``)."""
    return SafetyFilter(make_model(model_name),
                        FilterConfig(solver=backend, robot_radius=0.3, control_period=period,
                                     **CONFIGURATIONS[configuration]))


def check_and_evasion(filt, x, u, obstacles, age, status):
    """Return (check ran, it computed paths, evasion looked) on the step just taken, or Nones.

    The filter keeps no count: its own quick tests are asked again on the same state and
    obstacle set (a cache hit), outside the timed step.  None: the filter has no such part
    (a 3-D model, the check off) or no longer these private tests.
    """
    try:
        braking, evasion = filt._braking, filt._evasion
        prepared = filt._prepare(obstacles)
        checked = braking and status in CHECKED
        ran = checked and not filt._far_from_all(x, prepared, age)
        computed = ran and not filt._stop_certified(
            filt._paths.stop_bands(x, u, filt.config.control_period), prepared, age)
        looked = checked and evasion and filt._moving_near(x, prepared, age)
    except AttributeError:
        return None, None, None
    return ((ran if braking else None), (computed if braking else None),
            (looked if evasion else None))


class _Rollout:
    """One configuration's closed-loop rollout through a case's obstacles."""

    def __init__(self, configuration, model_name, backend, obstacles, steps, layout, rate):
        """Build the filter at ``rate`` Hz, start at rest, and step once (the set's cache)."""
        self.configuration = configuration
        self.model = make_model(model_name)
        self.x, self.goal, self.controller, _, self.substeps = CASES[model_name]
        self.period = 1.0 / rate
        self.x = self.x.copy()
        if layout == 'in_reach':
            self.goal = self.goal.copy()
            self.goal[0] = IN_REACH_GOAL_X
        self.filter = make_filter(model_name, backend, self.period, configuration)
        self.obstacles = obstacles
        self.filter.step(self.x, obstacles, self.controller(self.x, self.goal))
        self.samples = np.empty(steps)
        self.statuses = {}
        self.checks, self.paths, self.evasions = [], [], []

    def step(self, i):
        """Time step ``i``, count what ran, and integrate the plant over the period."""
        x = self.x
        u_nom = self.controller(x, self.goal)
        age = i * self.period
        begin = time.perf_counter()
        u, info = self.filter.step(x, self.obstacles, u_nom, obstacle_age=age)
        self.samples[i] = time.perf_counter() - begin
        status = info.status.value
        self.statuses[status] = self.statuses.get(status, 0) + 1
        ran, computed, looked = check_and_evasion(self.filter, x, u, self.obstacles, age,
                                                  status)
        self.checks.append(ran)
        self.paths.append(computed)
        self.evasions.append(looked)
        for _ in range(self.substeps):
            x = rk4_step(self.model, x, u, self.period / self.substeps)
        self.x = x


def _share(flags):
    """Return the share of True among ``flags``, or None when they are None (not applicable)."""
    return None if flags[0] is None else round(sum(flags) / len(flags), 3)


def time_case(model_name, backend, count, steps, rng, names=(DEFAULT, EQ7),
              layout='scattered', repeats=1, rate=RATE):
    """Return one record per configuration of a model/backend/obstacle-count case.

    The configurations step interleaved, each its own rollout, the order rotating every
    step; ``repeats`` rounds of that, each with fresh filters.  p50/p99 and their ratios
    to eq. 7 (``names`` must hold ``eq7``) are medians over the rounds.
    """
    obstacles = ObstacleSet.from_obstacles(LAYOUTS[layout](count, rng))
    runs = {name: [] for name in names}
    for _ in range(repeats):
        rollouts = [_Rollout(name, model_name, backend, obstacles, steps, layout, rate)
                    for name in names]
        for i in range(steps):
            shift = i % len(rollouts)
            for rollout in rollouts[shift:] + rollouts[:shift]:
                rollout.step(i)
        for rollout in rollouts:
            runs[rollout.configuration].append(rollout)
    p50 = {name: [float(np.percentile(r.samples, 50)) * 1e6 for r in rs]
           for name, rs in runs.items()}
    p99 = {name: [float(np.percentile(r.samples, 99)) * 1e6 for r in rs]
           for name, rs in runs.items()}
    records = []
    for name, rollouts in runs.items():
        config = rollouts[0].filter.config
        first = rollouts[0]
        records.append({
            'bench': 'core', 'model': model_name, 'backend': backend, 'obstacles': count,
            'vertices': VERTICES, 'layout': layout, 'rate_hz': rate, 'configuration': name,
            'barrier': config.barrier, 'cone_axis': config.cone_axis,
            'braking_check': bool(config.braking_check),
            'p50_us': round(float(np.median(p50[name])), 1),
            'p99_us': round(float(np.median(p99[name])), 1),
            'max_us': round(max(float(r.samples.max()) for r in rollouts) * 1e6, 1),
            'p50_ratio_to_eq7': round(float(np.median(np.divide(p50[name], p50[EQ7]))), 2),
            'p99_ratio_to_eq7': round(float(np.median(np.divide(p99[name], p99[EQ7]))), 2),
            'p50_us_runs': [round(v, 1) for v in p50[name]],
            'p99_us_runs': [round(v, 1) for v in p99[name]],
            'braking_check_share': _share(first.checks),
            'braking_paths_share': _share(first.paths),
            'evasion_share': _share(first.evasions),
            'steps': steps, 'repeats': repeats, 'statuses': first.statuses,
            'kernels': KERNELS, 'load_avg_1min': round(os.getloadavg()[0], 2)})
    return records


def _percentiles(prefix, seconds):
    """Return {prefix_p50_us, prefix_p99_us} of the samples."""
    us = np.asarray(seconds) * 1e6
    return {f'{prefix}_p50_us': round(float(np.percentile(us, 50)), 1),
            f'{prefix}_p99_us': round(float(np.percentile(us, 99)), 1)}


def time_rebuild(model_name, barrier, count, moving, rebuilds, rng, period=0.01):
    """Return one rebuild record: a fresh set, or a translated one, and its preparation.

    Fresh: ``ObstacleSet.from_obstacles`` + ``SafetyFilter.prepare`` (what a new
    shape costs).  Translated: ``ObstacleSet.translated`` of the first set +
    ``prepare`` (what the node's tracker and the in-process loop pay when
    obstacles only move).
    """
    config = FilterConfig(barrier=barrier, robot_radius=0.3)
    fresh_filter = SafetyFilter(make_model(model_name), config)
    moved_filter = SafetyFilter(make_model(model_name), config)
    obstacles = octagon_obstacles(count, rng)
    base = ObstacleSet.from_obstacles(obstacles)
    velocities = np.array([o.velocity for o in obstacles])
    times = {name: np.empty(rebuilds) for name in ('build', 'prepare', 'translate', 'reuse')}
    for i in range(rebuilds):
        obstacles[:moving] = [Obstacle(polygon=o.polygon + period * o.velocity[:2],
                                       velocity=o.velocity, z_min=o.z_min, z_max=o.z_max)
                              for o in obstacles[:moving]]
        offsets = np.zeros((len(base), 3))
        offsets[:moving] = (i + 1) * period * velocities[:moving]
        begin = time.perf_counter()
        obstacle_set = ObstacleSet.from_obstacles(obstacles)
        built = time.perf_counter()
        fresh_filter.prepare(obstacle_set)
        prepared = time.perf_counter()
        moved = base.translated(offsets)
        translated = time.perf_counter()
        moved_filter.prepare(moved)
        times['build'][i], times['prepare'][i] = built - begin, prepared - built
        times['translate'][i], times['reuse'][i] = (translated - prepared,
                                                    time.perf_counter() - translated)
    return {'bench': 'core_rebuild', 'model': model_name, 'barrier': barrier,
            'obstacles': count, 'moving': moving, 'vertices': VERTICES,
            **_percentiles('from_obstacles', times['build']),
            **_percentiles('prepare', times['prepare']),
            **_percentiles('total', times['build'] + times['prepare']),
            **_percentiles('translated_total', times['translate'] + times['reuse']),
            'rebuilds': rebuilds, 'load_avg_1min': round(os.getloadavg()[0], 2)}


def rebuild_records(models, counts, moving, rebuilds):
    """Time the rebuild for every model, barrier and obstacle count; print a table."""
    records = []
    print(f'{"rebuild":<10} {"barrier":<18} {"N":>4} {"set p50":>8} {"prep p50":>8} '
          f'{"total p50":>9} {"total p99":>9} {"moved p50":>9} {"moved p99":>9}'
          f'  (us, {moving} moving)')
    for model_name in models:
        for barrier in CONE_MODELS:
            for count in counts:
                rng = np.random.default_rng([11, MODELS.index(model_name), count])
                record = time_rebuild(model_name, barrier, count, min(moving, count), rebuilds,
                                      rng)
                records.append(record)
                print(f'{model_name:<10} {barrier:<18} {count:>4} '
                      f'{record["from_obstacles_p50_us"]:>8.1f} {record["prepare_p50_us"]:>8.1f} '
                      f'{record["total_p50_us"]:>9.1f} {record["total_p99_us"]:>9.1f} '
                      f'{record["translated_total_p50_us"]:>9.1f} '
                      f'{record["translated_total_p99_us"]:>9.1f}', flush=True)
    return records


STARTUP_SCRIPT = """
import json, time
start = time.perf_counter()
from polyc2bf_ros.core.safety_filter import compile_kernels
imported = time.perf_counter()
compile_kernels()
constructed = time.perf_counter()
rss = [int(line.split()[1]) for line in open('/proc/self/status') if line.startswith('VmRSS')]
print(json.dumps([imported - start, constructed - imported, rss[0] / 1024]))
"""
STARTUP_MODES = (('ahead_of_time', 'aot'), ('jit_cold_cache', 'jit'), ('jit_warm_cache', 'jit'))


def startup_records():
    """Return start-up records (import, one filter per model and barrier, RSS), fresh processes.

    Ahead of time (the built extension), then just in time with an empty numba
    cache (compiling) and again with the cache it filled (loading).
    """
    records = []
    with tempfile.TemporaryDirectory() as cache:
        for label, mode in STARTUP_MODES:
            env = dict(os.environ, NUMBA_CACHE_DIR=cache, POLYC2BF_KERNELS=mode)
            result = subprocess.run([sys.executable, '-c', STARTUP_SCRIPT], env=env, check=True,
                                    capture_output=True, text=True)
            import_s, construct_s, rss_mb = json.loads(result.stdout.splitlines()[-1])
            records.append({'bench': 'core_startup', 'kernels': label,
                            'import_s': round(import_s, 3),
                            'construct_all_s': round(construct_s, 3), 'rss_mb': round(rss_mb, 1),
                            'load_avg_1min': round(os.getloadavg()[0], 2)})
            print(f'start-up, {label}: import {import_s:.2f} s, one filter per model '
                  f'and barrier {construct_s:.2f} s, RSS {rss_mb:.0f} MB', flush=True)
    return records


def _cell(value, width, spec='.2f'):
    """Return ``value`` formatted right-aligned in ``width``, '-' for None."""
    return f'{"-":>{width}}' if value is None else f'{value:>{width}{spec}}'


def step_records(args, names, layout, counts):
    """Time every model, backend, obstacle count and configuration; print a table."""
    records = []
    width = max(len(name) for name in [*names, 'configuration'])
    print(f'{"model":<10} {"backend":<10} {"layout":<9} {"N":>4} {"configuration":<{width}} '
          f'{"p50 us":>8} {"p99 us":>8} {"max us":>8} {"p50/eq7":>7} {"p99/eq7":>7} '
          f'{"check":>6} {"paths":>6} {"evade":>6}  statuses')
    for model_name in args.models:
        for backend in args.backends:
            for count in counts:
                # One seed per case: a case's obstacles do not depend on which others ran.
                rng = np.random.default_rng([7, MODELS.index(model_name), count])
                for record in time_case(model_name, backend, count, args.steps, rng, names,
                                        layout, args.repeats, args.rate):
                    records.append(record)
                    print(f'{model_name:<10} {backend:<10} {layout:<9} {count:>4} '
                          f'{record["configuration"]:<{width}} {record["p50_us"]:>8.1f} '
                          f'{record["p99_us"]:>8.1f} {record["max_us"]:>8.1f} '
                          f'{record["p50_ratio_to_eq7"]:>7.2f} '
                          f'{record["p99_ratio_to_eq7"]:>7.2f} '
                          f'{_cell(record["braking_check_share"], 6, ".0%")} '
                          f'{_cell(record["braking_paths_share"], 6, ".0%")} '
                          f'{_cell(record["evasion_share"], 6, ".0%")}  '
                          f'{record["statuses"]}', flush=True)
    return records


def main(argv=None):
    """Run all cases, print a table and write the JSON records."""
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument('--steps', type=int, default=None,
                        help='timed steps per rollout (default: 20 s at the rate)')
    parser.add_argument('--rate', type=float, default=RATE,
                        help=f'control rate [Hz] of the filter and the rollout (default {RATE:g})')
    parser.add_argument('--repeats', type=int, default=3,
                        help='interleaved rounds per case; p50, p99 and ratios are medians')
    parser.add_argument('--out', default=None,
                        help='JSON records (default bench/results/core.json, '
                             'bench/results/core_in_reach.json with --in-reach)')
    parser.add_argument('--models', nargs='+', choices=MODELS, default=MODELS)
    parser.add_argument('--backends', nargs='+', choices=BACKENDS, default=BACKENDS)
    parser.add_argument('--counts', nargs='+', type=int, default=None,
                        help=f'obstacle counts (default {" ".join(map(str, OBSTACLE_COUNTS))}; '
                             'with --in-reach 50)')
    parser.add_argument('--barrier', action='append', metavar='NAME',
                        help='filter configuration to time, repeatable (default: default); eq7 '
                             f'is always timed too; one of {", ".join(CONFIGURATIONS)}')
    parser.add_argument('--in-reach', action='store_true',
                        help='obstacles in two rows along the way, within the braking '
                             "check's reach on every step")
    parser.add_argument('--no-startup', action='store_true', help='skip the start-up timing')
    parser.add_argument('--rebuilds', type=int, default=500,
                        help='obstacle-set rebuilds timed per case (0: skip)')
    parser.add_argument('--moving', type=int, default=10,
                        help='obstacles that move between rebuilds')
    args = parser.parse_args(argv)
    args.steps = args.steps or round(ROLLOUT_S * args.rate)
    names = configurations(args.barrier)
    layout = 'in_reach' if args.in_reach else 'scattered'
    counts = args.counts or ((50,) if args.in_reach else OBSTACLE_COUNTS)
    out = args.out or ('bench/results/core_in_reach.json' if args.in_reach
                       else 'bench/results/core.json')
    require_installed_checkout()
    print(f'load average at start: {" ".join(f"{v:.2f}" for v in os.getloadavg())}; '
          f'kernels {KERNELS}')
    records = [] if args.no_startup else startup_records()
    if args.rebuilds:
        records += rebuild_records(args.models, counts, args.moving, args.rebuilds)
    records += step_records(args, names, layout, counts)
    print(f'load average at end: {" ".join(f"{v:.2f}" for v in os.getloadavg())}')
    write_records(records, out)


if __name__ == '__main__':
    main()
