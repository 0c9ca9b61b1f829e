"""Clutter safety of each cone model: 30 random convex polygons, many seeds, numpy plant.

Usage: python bench/bench_clutter.py [--seeds 50] [--out bench/results/clutter.json]

Same setup as test/core/test_closed_loop.py::test_clutter_zero_collisions (unicycle
and 2-D point mass, 50 Hz control, 20 s, robot radius 0.3 m around the body's centre; the
unicycle's guarded point is 0.2 m ahead, so it keeps 0.5 m), for the paper's barriers as
the paper has them (no braking check) and for the default (``polyc2bf_horizon`` with the
braking check).
"""
import argparse
import time

import numpy as np
from bench_io import require_installed_checkout, write_records

from polyc2bf_ros.core.models import make_model
from polyc2bf_ros.core.nominal import PointMassGoalController, UnicycleGoalController
from polyc2bf_ros.core.safety_filter import FilterConfig, FilterStatus, SafetyFilter
from polyc2bf_ros.core.simulate import random_clutter, rollout

GOAL = np.array([12.0, 0.0])
CASES = {
    'unicycle': (UnicycleGoalController(), np.array([-0.2, 0.0, 0.0, 0.0, 0.0])),
    'point_mass_2d': (PointMassGoalController(), np.zeros(4)),
}
#: label -> FilterConfig settings
BARRIERS = {
    'polyc2bf_paper': {'barrier': 'polyc2bf_paper', 'braking_check': False},
    'polyc2bf_inflated': {'barrier': 'polyc2bf_inflated', 'braking_check': False},
    'c3bf': {'barrier': 'c3bf', 'braking_check': False},
    'default': {},
}


def run_case(model_name, barrier, seeds):
    """Return one record: collisions, goals reached and fallback use over ``seeds``."""
    model = make_model(model_name)
    controller, start = CASES[model_name]
    filt = SafetyFilter(model, FilterConfig(robot_radius=0.3, control_period=0.02,
                                            **BARRIERS[barrier]))
    collisions, goals, clearances, fallbacks, steps = [], 0, [], 0, 0
    for seed in seeds:
        run = rollout(model, filt, controller, start, GOAL, random_clutter(seed),
                      duration=20.0, physics_step=0.005)
        if run.min_clearance <= 0.0:
            collisions.append(seed)
        goals += bool(np.linalg.norm(model.body_centre(run.states[-1]) - GOAL) < 0.5)
        clearances.append(run.min_clearance)
        fallbacks += sum(s != FilterStatus.OK for s in run.statuses)
        steps += len(run.statuses)
    return {'bench': 'clutter', 'model': model_name, 'barrier': barrier, 'seeds': len(seeds),
            'collisions': len(collisions), 'collision_seeds': collisions,
            'goal_reached': goals, 'min_clearance_m': round(float(min(clearances)), 4),
            'median_min_clearance_m': round(float(np.median(clearances)), 4),
            'non_ok_step_frac': round(fallbacks / steps, 4)}


def main(argv=None):
    """Run every model x barrier, print a table and write the JSON records."""
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument('--seeds', type=int, default=50)
    parser.add_argument('--out', default='bench/results/clutter.json')
    args = parser.parse_args(argv)
    require_installed_checkout()
    seeds = range(args.seeds)
    records = []
    print(f'{"model":<14} {"barrier":<18} {"collisions":>10} {"goals":>6} {"min clr m":>9} '
          f'{"non-ok":>7} {"s":>5}')
    for model_name in CASES:
        for barrier in BARRIERS:
            start = time.perf_counter()
            record = run_case(model_name, barrier, seeds)
            records.append(record)
            print(f'{model_name:<14} {barrier:<18} {record["collisions"]:>5}/{len(seeds):<4} '
                  f'{record["goal_reached"]:>6} {record["min_clearance_m"]:>9.4f} '
                  f'{record["non_ok_step_frac"]:>7.3f} {time.perf_counter() - start:>5.0f}',
                  flush=True)
    write_records(records, args.out)


if __name__ == '__main__':
    main()
