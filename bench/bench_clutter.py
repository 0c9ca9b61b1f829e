"""Clutter: 30 random convex polygons, many seeds, the node's whole decision on a numpy plant.

Usage: python bench/bench_clutter.py [--seeds 50] [--duration 60] [--models ...] [--variants ...]
                                    [--out bench/results/clutter.json]

Each run is the node's ``ControlDecision`` (filter, braking check, deadlock report and
its resolution) built from a shipped parameter file, fed every period with the plant's
state and the nominal law's velocity command, on a numpy plant (RK4, 4 substeps per
period).  Unicycle: ``config/quadruped.yaml`` (robot radius 0.3 m about the body's
centre, guarded point 0.2 m ahead, so it keeps 0.5 m; 1 m/s^2, 2 rad/s^2; 100 Hz).
2-D point mass: ``config/holonomic_base.yaml`` with the same 0.3 m radius.  The goal
lies 12.2 m ahead (12 s at the nominal's 1 m/s); a run ends at the goal (body centre
within 0.5 m) or after ``--duration`` s.  The paper's barriers run as the paper has them
(no braking check, no deadlock resolution) beside the shipped default.
"""
import argparse
import time
from pathlib import Path

import numpy as np
from bench_io import require_installed_checkout, write_records

from polyc2bf_ros.core.decision import ControlDecision, ObstacleSnapshot
from polyc2bf_ros.filter_parameters import build_filter, load_parameters
from sim_bridge.nominal import PointMassGoalController, UnicycleGoalController
from sim_bridge.rollout import clearance, random_clutter, rk4_step

CONFIG = Path(__file__).resolve().parents[1] / 'config'
GOAL = np.array([12.0, 0.0])
GOAL_TOLERANCE = 0.5
SUBSTEPS = 4
#: model -> (parameter file, nominal law, start state)
CASES = {
    'unicycle': ('quadruped.yaml', UnicycleGoalController(), np.array([-0.2, 0, 0, 0, 0.0])),
    'point_mass_2d': ('holonomic_base.yaml', PointMassGoalController(), np.zeros(4)),
}
PAPER = {'filter.braking_check': False, 'deadlock_resolution': 'none'}
#: label -> parameter overrides of the shipped file
VARIANTS = {
    'polyc2bf_paper': {'filter.barrier': 'polyc2bf_paper', **PAPER},
    'polyc2bf_inflated': {'filter.barrier': 'polyc2bf_inflated', **PAPER},
    'c3bf': {'filter.barrier': 'c3bf', **PAPER},
    'default': {},
    # the default before the route: circulation after 3 s held
    'circulate': {'deadlock_resolution': 'circulate', 'deadlock_time': 3.0},
}


def run_seed(model_name, variant, seed, duration):
    """Return one run's numbers: reached, time, min clearance, statuses, h < 0, reports."""
    config, controller, start = CASES[model_name]
    parameters = {**load_parameters([str(CONFIG / config)], (), 'safety_filter'),
                  'filter.robot_radius': 0.3, **VARIANTS[variant]}
    settings = build_filter(parameters)
    command_filter = settings.command_filter
    decision = ControlDecision(command_filter, dict.fromkeys(settings.timeouts, 0.0),
                               settings.block_if_invalid, 0.0, settings.deadlock,
                               settings.resolution, settings.route)
    model, period = command_filter.model, command_filter.safety_filter.config.control_period
    radius = command_filter.safety_filter.config.robot_radius
    obstacles = random_clutter(seed)
    snapshot = ObstacleSnapshot(obstacles=obstacles, t_ref=0.0, received=0.0)
    x, yaw_index = start.copy(), 2 if model_name == 'unicycle' else None
    steps, non_ok, negative_h, min_clearance = int(round(duration / period)), 0, 0, np.inf
    for k in range(steps):
        now = k * period
        yaw = float(x[yaw_index]) if yaw_index is not None else 0.0
        decision.odometry(now, x, yaw, now)
        decision.command(now, controller.velocity_command(x, GOAL))
        decision.obstacles(snapshot)
        result = decision.step(now)
        info = result.info
        non_ok += info is None or info.status.value != 'ok'
        negative_h += info is not None and info.min_h < 0.0
        u = model.clip_input(command_filter.interface.nominal_input(x, result.command, yaw)
                             * command_filter.interface.tau / period)
        for _ in range(SUBSTEPS):
            x = rk4_step(model, x, u, period / SUBSTEPS)
        min_clearance = min(min_clearance, clearance(model, x, obstacles, radius))
        if np.linalg.norm(model.body_centre(x) - GOAL) < GOAL_TOLERANCE:
            return True, now + period, min_clearance, non_ok, negative_h, k + 1, decision
    return False, duration, min_clearance, non_ok, negative_h, steps, decision


def run_case(model_name, variant, seeds, duration):
    """Return one record over ``seeds``: collisions, goals and how the runs went."""
    collisions, goal_times, clearances, non_ok, negative_h, steps, reports = [], [], [], 0, 0, \
        0, 0
    for seed in seeds:
        reached, elapsed, clear, bad, negative, count, decision = run_seed(
            model_name, variant, seed, duration)
        if clear <= 0.0:
            collisions.append(seed)
        if reached:
            goal_times.append(elapsed)
        clearances.append(clear)
        non_ok, negative_h, steps = non_ok + bad, negative_h + negative, steps + count
        reports += decision.deadlock.onsets
    return {'bench': 'clutter', 'model': model_name, 'barrier': variant, 'seeds': len(seeds),
            'duration_s': duration, 'collisions': len(collisions), 'collision_seeds': collisions,
            'goal_reached': len(goal_times),
            'median_time_to_goal_s': round(float(np.median(goal_times)), 2)
            if goal_times else None,
            'min_clearance_m': round(float(min(clearances)), 4),
            'median_min_clearance_m': round(float(np.median(clearances)), 4),
            'non_ok_step_frac': round(non_ok / steps, 4),
            'negative_h_step_frac': round(negative_h / steps, 5),
            'deadlock_reports': reports}


def main(argv=None):
    """Run every model x variant, print a table and write the JSON records."""
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument('--seeds', type=int, default=50)
    parser.add_argument('--duration', type=float, default=60.0, help='s per run (60)')
    parser.add_argument('--models', nargs='+', choices=CASES, default=list(CASES))
    parser.add_argument('--variants', nargs='+', choices=VARIANTS, default=list(VARIANTS))
    parser.add_argument('--out', default='bench/results/clutter.json')
    args = parser.parse_args(argv)
    require_installed_checkout()
    seeds = range(args.seeds)
    records = []
    print(f'{"model":<14} {"variant":<18} {"collisions":>10} {"goals":>6} {"t goal s":>8} '
          f'{"min clr m":>9} {"non-ok":>7} {"h<0":>7} {"reports":>7} {"s":>5}')
    for model_name in args.models:
        for variant in args.variants:
            start = time.perf_counter()
            record = run_case(model_name, variant, seeds, args.duration)
            records.append(record)
            t_goal = record['median_time_to_goal_s']
            print(f'{model_name:<14} {variant:<18} {record["collisions"]:>5}/{len(seeds):<4} '
                  f'{record["goal_reached"]:>6} {t_goal if t_goal is not None else "-":>8} '
                  f'{record["min_clearance_m"]:>9.4f} {record["non_ok_step_frac"]:>7.3f} '
                  f'{record["negative_h_step_frac"]:>7.4f} {record["deadlock_reports"]:>7} '
                  f'{time.perf_counter() - start:>5.0f}', flush=True)
    write_records(records, args.out)


if __name__ == '__main__':
    main()
