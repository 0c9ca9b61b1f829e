"""How far ahead a moving cylinder's motion can be predicted: the dynamic suite's worlds.

Usage: python bench/bench_prediction.py [--samples 40] [--horizons 0.5 1 1.5 2 2.5]
    [--config config/diff_drive.yaml] [--out bench/results/prediction.json]

The filter predicts a moving obstacle along its stated velocity (constant velocity, CV) and
allows it to stray from that by ``obstacle_velocity_error`` t + ``braking_obstacle_accel``
t^2 / 2 (doc/design.md 3.8, 3.10).  This measures that model against the dynamic suite's
cylinders (``sim_bridge.dynamic_worlds``: constant speed along closed C2 loops, up to
2 m/s^2 of centripetal acceleration), with their true state, so that what is left is the
model's error, not an estimator's:

- ``cv``: c(t0) + v(t0) h;
- ``ctrv``: the arc of constant speed and turn rate omega = (v x a) / |v|^2 (a the
  acceleration, by central differences of the trajectory's velocity over 10 ms), what a
  tracker that also estimated the turn rate could predict.

Per world, ``--samples`` start times t0 uniform in [0, TIME_LIMIT - the longest horizon],
every cylinder at each.  The table gives, per difficulty and horizon h, the distance from
each prediction to the true centre at t0 + h (p50 / p90 / p99, m), and the share of CV
predictions whose error is within the bound of ``--config`` (``bound``).

Records (``bench`` = ``prediction``): ``difficulty``, ``horizon_s``, ``predictions``,
``cv_p50_m``, ``cv_p90_m``, ``cv_p99_m``, ``ctrv_p50_m``, ``ctrv_p90_m``, ``ctrv_p99_m``,
``bound_m``, ``cv_within_bound``, ``obstacle_velocity_error``, ``braking_obstacle_accel``,
``samples_per_world``, ``seed``.
"""
import argparse
import sys

import numpy as np
from bench_io import require_installed_checkout, write_records

from polyc2bf_ros.core.safety_filter import FilterConfig
from polyc2bf_ros.filter_parameters import load_parameters
from sim_bridge.dynamic_worlds import DEFAULT_SEED, DIFFICULTIES, dynamic_worlds, TIME_LIMIT

DIFFERENCE = 0.01  # s: the central difference of the velocity that gives the acceleration


def filter_bounds(path):
    """Return (obstacle_velocity_error [m/s], braking_obstacle_accel [m/s^2]) of a config.

    As the node reads the file (``load_parameters``); a bound it leaves out is the
    filter's default.
    """
    values = load_parameters([path], (), '')
    return tuple(float(values.get(f'filter.{name}', getattr(FilterConfig, name)))
                 for name in ('obstacle_velocity_error', 'braking_obstacle_accel'))


def _states(trajectories, time):
    """Return the cylinders' centres and velocities (N, 2) each at ``time``."""
    return (np.array([trajectory.position(time) for trajectory in trajectories], dtype=float),
            np.array([trajectory.velocity(time) for trajectory in trajectories], dtype=float))


def predictions(trajectories, t0, horizons):
    """Return {h: (cv errors (N,), ctrv errors (N,))} of every cylinder from ``t0``."""
    centre, velocity = _states(trajectories, t0)
    accel = (_states(trajectories, t0 + DIFFERENCE)[1]
             - _states(trajectories, t0 - DIFFERENCE)[1]) / (2 * DIFFERENCE)
    speed = np.hypot(velocity[:, 0], velocity[:, 1])
    turn = ((velocity[:, 0] * accel[:, 1] - velocity[:, 1] * accel[:, 0])
            / np.maximum(speed ** 2, 1e-12))
    heading = np.arctan2(velocity[:, 1], velocity[:, 0])
    result = {}
    for h in horizons:
        truth = _states(trajectories, t0 + h)[0]
        cv = centre + velocity * h
        # The arc's chord, written to stay exact as the turn rate goes to 0.
        half = 0.5 * turn * h
        chord = speed * h * np.sinc(half / np.pi)
        ctrv = centre + chord[:, None] * np.column_stack((np.cos(heading + half),
                                                          np.sin(heading + half)))
        result[h] = (np.hypot(*(cv - truth).T), np.hypot(*(ctrv - truth).T))
    return result


def measure(difficulty, horizons, samples, rng, bounds):
    """Return one record per horizon for the worlds of ``difficulty``."""
    errors = {h: ([], []) for h in horizons}
    for world in dynamic_worlds(DEFAULT_SEED):
        if world.difficulty != difficulty:
            continue
        for t0 in rng.uniform(DIFFERENCE, TIME_LIMIT - max(horizons), samples):
            for h, (cv, ctrv) in predictions(world.cylinders, float(t0), horizons).items():
                errors[h][0].append(cv)
                errors[h][1].append(ctrv)
    velocity_error, accel = bounds
    records = []
    for h in horizons:
        cv, ctrv = np.concatenate(errors[h][0]), np.concatenate(errors[h][1])
        bound = velocity_error * h + 0.5 * accel * h * h
        record = {'bench': 'prediction', 'difficulty': difficulty, 'horizon_s': h,
                  'predictions': int(cv.size)}
        for name, values in (('cv', cv), ('ctrv', ctrv)):
            for q in (50, 90, 99):
                record[f'{name}_p{q}_m'] = round(float(np.percentile(values, q)), 3)
        record.update(bound_m=round(bound, 3),
                      cv_within_bound=round(float(np.mean(cv <= bound)), 3),
                      obstacle_velocity_error=velocity_error, braking_obstacle_accel=accel,
                      samples_per_world=samples, seed=DEFAULT_SEED)
        records.append(record)
    return records


def main(argv=None):
    """Measure every difficulty, print the table and write the JSON records."""
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument('--samples', type=int, default=40, help='start times per world')
    parser.add_argument('--horizons', type=float, nargs='+', default=[0.5, 1.0, 1.5, 2.0, 2.5])
    parser.add_argument('--config', default='config/diff_drive.yaml',
                        help='parameter file whose filter bounds are checked')
    parser.add_argument('--out', default='bench/results/prediction.json')
    args = parser.parse_args(argv)
    if args.samples < 1 or not all(0.0 < h < TIME_LIMIT for h in args.horizons):
        parser.error(f'--samples must be >= 1 and every horizon in (0, {TIME_LIMIT:g}) s')
    require_installed_checkout()
    bounds = filter_bounds(args.config)
    rng = np.random.default_rng(5)
    print(f'bound = {bounds[0]:g} h + {bounds[1]:g} h^2 / 2 ({args.config})')
    print(f'{"difficulty":>10} {"h [s]":>6} {"n":>6} {"CV p50/p90/p99 [m]":>20} '
          f'{"CTRV p50/p90/p99 [m]":>21} {"bound [m]":>9} {"CV within":>9}')
    records = []
    for difficulty in DIFFICULTIES:
        for record in measure(difficulty, args.horizons, args.samples, rng, bounds):
            records.append(record)
            cv = '/'.join(f'{record[f"cv_p{q}_m"]:.2f}' for q in (50, 90, 99))
            ctrv = '/'.join(f'{record[f"ctrv_p{q}_m"]:.2f}' for q in (50, 90, 99))
            print(f'{difficulty:>10} {record["horizon_s"]:>6.1f} {record["predictions"]:>6} '
                  f'{cv:>20} {ctrv:>21} {record["bound_m"]:>9.2f} '
                  f'{record["cv_within_bound"]:>9.1%}', flush=True)
    write_records(records, args.out)
    return 0


if __name__ == '__main__':
    sys.exit(main())
