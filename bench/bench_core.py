"""Benchmark one SafetyFilter.step: p50/p99/max latency vs obstacle count and backend.

Usage: python bench/bench_core.py [--steps N] [--out bench/results/core.json]
       [--models unicycle ...] [--backends daqp ...] [--counts 1 10 ...] [--no-startup]
       [--rebuilds N] [--moving M]

Every step of a closed-loop numpy rollout is timed: the robot starts at rest
and its nominal controller drives it through N random 8-gons (2-20 m around
the start, drifting at up to 0.1 m/s) towards a goal 15 m away, so the mix of
ok / slack steps is the one the filter meets in operation.  The obstacle set
is built once per case, as the node does once per obstacle message.

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
from polyc2bf_ros.core.models import make_model
from polyc2bf_ros.core.obstacles.obstacle_set import Obstacle, ObstacleSet
from polyc2bf_ros.core.safety_filter import CONE_MODELS, FilterConfig, SafetyFilter
from sim_bridge.nominal import QuadrotorGoalController, UnicycleGoalController
from sim_bridge.rollout import rk4_step

OBSTACLE_COUNTS = (1, 10, 50, 200)
VERTICES = 8
BACKENDS = ('daqp', 'proxsuite')
MODELS = ('unicycle', 'quadrotor')


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


CASES = {
    # model: (start state, goal, controller, control period, physics substeps)
    'unicycle': (np.zeros(5), np.array([15.0, 0.0]), UnicycleGoalController(), 0.01, 1),
    'quadrotor': (np.array([0, 0, 1.0] + [0.0] * 9), np.array([15.0, 0.0, 1.0]),
                  QuadrotorGoalController(), 0.01, 5),
}


def time_case(model_name, backend, count, steps, rng):
    """Return one result record for a model/backend/obstacle-count case."""
    model = make_model(model_name)
    start, goal, controller, period, substeps = CASES[model_name]
    filt = SafetyFilter(model, FilterConfig(solver=backend, robot_radius=0.3,
                                            control_period=period))
    obstacles = octagons(count, rng)
    x = start.copy()
    filt.step(x, obstacles, controller(x, goal))  # builds the per-obstacle-set cache
    samples = np.empty(steps)
    statuses = {}
    for i in range(steps):
        u_nom = controller(x, goal)
        begin = time.perf_counter()
        u, info = filt.step(x, obstacles, u_nom, obstacle_age=i * period)
        samples[i] = time.perf_counter() - begin
        statuses[info.status.value] = statuses.get(info.status.value, 0) + 1
        for _ in range(substeps):
            x = rk4_step(model, x, u, period / substeps)
    us = samples * 1e6
    return {'bench': 'core', 'model': model_name, 'backend': backend, 'obstacles': count,
            'vertices': VERTICES, 'p50_us': round(float(np.percentile(us, 50)), 1),
            'p99_us': round(float(np.percentile(us, 99)), 1),
            'max_us': round(float(us.max()), 1), 'steps': steps, 'statuses': statuses,
            'load_avg_1min': round(os.getloadavg()[0], 2)}


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


def main(argv=None):
    """Run all cases, print a table and write the JSON records."""
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument('--steps', type=int, default=2000)
    parser.add_argument('--out', default='bench/results/core.json')
    parser.add_argument('--models', nargs='+', choices=MODELS, default=MODELS)
    parser.add_argument('--backends', nargs='+', choices=BACKENDS, default=BACKENDS)
    parser.add_argument('--counts', nargs='+', type=int, default=OBSTACLE_COUNTS)
    parser.add_argument('--no-startup', action='store_true', help='skip the start-up timing')
    parser.add_argument('--rebuilds', type=int, default=500,
                        help='obstacle-set rebuilds timed per case (0: skip)')
    parser.add_argument('--moving', type=int, default=10,
                        help='obstacles that move between rebuilds')
    args = parser.parse_args(argv)
    require_installed_checkout()
    print(f'load average at start: {" ".join(f"{v:.2f}" for v in os.getloadavg())}')
    records = [] if args.no_startup else startup_records()
    if args.rebuilds:
        records += rebuild_records(args.models, args.counts, args.moving, args.rebuilds)
    print(f'{"model":<10} {"backend":<10} {"N":>4} {"p50 us":>8} {"p99 us":>8} {"max us":>8}  '
          'statuses')
    for model_name in args.models:
        for backend in args.backends:
            for count in args.counts:
                # One seed per case: a case's obstacles do not depend on which others ran.
                rng = np.random.default_rng([7, MODELS.index(model_name), count])
                record = time_case(model_name, backend, count, args.steps, rng)
                records.append(record)
                print(f'{model_name:<10} {backend:<10} {count:>4} {record["p50_us"]:>8.1f} '
                      f'{record["p99_us"]:>8.1f} {record["max_us"]:>8.1f}  '
                      f'{record["statuses"]}', flush=True)
    print(f'load average at end: {" ".join(f"{v:.2f}" for v in os.getloadavg())}')
    write_records(records, args.out)


if __name__ == '__main__':
    main()
