"""Benchmark one SafetyFilter.step: p50/p99/max latency vs obstacle count and backend.

Usage: python bench/bench_core.py [--repeats N] [--out bench/results/core.json]

The obstacle set is built once per case (as the node does once per obstacle
message); each timed step uses a slightly different state, as in closed loop.
"""
import argparse
import json
import time
from pathlib import Path

import numpy as np

from polyc2bf_ros.core.geometry import convex_hull
from polyc2bf_ros.core.models import make_model
from polyc2bf_ros.core.obstacles import Obstacle, ObstacleSet
from polyc2bf_ros.core.safety_filter import FilterConfig, SafetyFilter

OBSTACLE_COUNTS = (1, 10, 50, 200)
VERTICES = 8
BACKENDS = ('daqp', 'proxsuite')
MODELS = ('unicycle', 'quadrotor')


def octagons(count, rng):
    """Return ``count`` convex 8-gons scattered 1.5-15 m around the origin."""
    angles = np.linspace(0.0, 2.0 * np.pi, VERTICES, endpoint=False)
    obstacles = []
    for _ in range(count):
        distance, bearing = rng.uniform(1.5, 15.0), rng.uniform(-np.pi, np.pi)
        centre = distance * np.array([np.cos(bearing), np.sin(bearing)])
        radii = rng.uniform(0.2, 0.6) * rng.uniform(0.8, 1.0, VERTICES)
        polygon = convex_hull(centre + np.column_stack([radii * np.cos(angles),
                                                        radii * np.sin(angles)]))
        obstacles.append(Obstacle(polygon=polygon, velocity=rng.uniform(-0.3, 0.3, 3),
                                  z_min=0.0, z_max=rng.uniform(0.5, 3.0)))
    return ObstacleSet.from_obstacles(obstacles)


def base_case(model_name):
    """Return (state, nominal input) for a robot moving at ~1 m/s towards +x."""
    if model_name == 'unicycle':
        return np.array([0.0, 0.0, 0.0, 1.0, 0.1]), np.array([1.0, 0.0])
    state = np.zeros(12)
    state[2], state[3] = 1.0, 1.0
    return state, np.full(4, 0.08)


def time_case(model_name, backend, count, repeats, rng):
    """Return one result record for a model/backend/obstacle-count case."""
    model = make_model(model_name)
    filt = SafetyFilter(model, FilterConfig(solver=backend, robot_radius=0.3))
    obstacles = octagons(count, rng)
    state, u_nom = base_case(model_name)
    noise = rng.normal(scale=0.01, size=(repeats, state.size))
    filt.step(state, obstacles, u_nom)  # builds the per-obstacle-set cache, like the node
    samples = np.empty(repeats)
    statuses = {}
    for i in range(repeats):
        start = time.perf_counter()
        _, info = filt.step(state + noise[i], obstacles, u_nom)
        samples[i] = time.perf_counter() - start
        statuses[info.status.value] = statuses.get(info.status.value, 0) + 1
    us = samples * 1e6
    return {'bench': 'core', 'model': model_name, 'backend': backend, 'obstacles': count,
            'vertices': VERTICES, 'p50_us': round(float(np.percentile(us, 50)), 1),
            'p99_us': round(float(np.percentile(us, 99)), 1),
            'max_us': round(float(us.max()), 1), 'repeats': repeats,
            'statuses': statuses}


def main(argv=None):
    """Run all cases, print a table and write the JSON records."""
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument('--repeats', type=int, default=3000)
    parser.add_argument('--out', default='bench/results/core.json')
    args = parser.parse_args(argv)
    rng = np.random.default_rng(7)
    records = []
    print(f'{"model":<10} {"backend":<10} {"N":>4} {"p50 us":>8} {"p99 us":>8} {"max us":>8}')
    for model_name in MODELS:
        for backend in BACKENDS:
            for count in OBSTACLE_COUNTS:
                record = time_case(model_name, backend, count, args.repeats, rng)
                records.append(record)
                print(f'{model_name:<10} {backend:<10} {count:>4} {record["p50_us"]:>8.1f} '
                      f'{record["p99_us"]:>8.1f} {record["max_us"]:>8.1f}', flush=True)
    out = Path(args.out)
    out.parent.mkdir(parents=True, exist_ok=True)
    out.write_text(json.dumps(records, indent=1) + '\n')
    print(f'wrote {out}')


if __name__ == '__main__':
    main()
