"""Wall time of ``evaluate --suite barn`` for one filter x one nominal, and its geometry choices.

Usage: python bench/bench_barn.py [--filter default] [--nominal path] [--jobs 2]
       [--limit K] [--geometry-worlds 10] [--stalls 8] [--check-rounds 3]
       [--out bench/results/barn.json]

``wall``: ``barn_suite.run_barn`` over the shipped worlds exactly as ``evaluate``
runs them (``--jobs`` processes, default the CPU count), against the issue's
budget of 240 s for the 200 worlds; with the CPU seconds of all processes and
the load average, since the machine is shared.

``geometry`` (on the first ``--geometry-worlds`` worlds, in this process): what
the choices in ``sim_bridge/barn.py`` cost and save.

- PyBullet bodies made on first use: at most the cylinders whose bounding box
  came within the search range (0.5 m) of the disc's reach along the recorded
  run are made, against all; the world's build time, and what making one body
  costs (``createMultiBody`` of a cylinder, timed alone);
- a distance cut-off of the filter's obstacles is not exact: along the
  recorded runs (every ``STRIDE``-th period), the filter's answer with every
  cylinder against only those whose centre is within D of the robot, and the
  step time of both (the cut set is built anew each step, which a real cut-off
  would also have to do as the robot moves).

``braking_check_barrier``: the barrier test of the braking check (doc/design.md 3.10)
against the clearance test alone, in this process, on the runs of ``CHECK_RUNS`` (where
the clearance test alone left the safe set, and world 1), on and off alternately for
``--check-rounds`` rounds: per setting the medians over its runs of the step time p50 /
p99 as ``evaluate`` records it, the successes and the runs with some h < 0.

``stall``: the first ``--stalls`` deadlocked runs of ``wall``, run again; at
their last period the filter's status, speed, nominal and safe speed, its active
rows and their cylinders' gaps to the disc, the smallest h against margin / gamma
(where h_dot + gamma h >= margin holds at rest), and the statuses of the last
STOP_TIME s.
"""
import argparse
import collections
import os
import resource
import time

import numpy as np
import pybullet as pb
from bench_io import require_installed_checkout, write_records

from polyc2bf_ros.core.obstacles.obstacle_set import Obstacle, ObstacleSet
from polyc2bf_ros.filter_parameters import build_filter, load_parameters
from sim_bridge.barn import BarnReferee, load_worlds, ROBOT_NAME, STOP_TIME, WORLDS_FILE
from sim_bridge.closed_loop import run_in_process
from sim_bridge.evaluation.arguments import resolve_filters
from sim_bridge.evaluation.barn_suite import run_barn, run_world
from sim_bridge.launcher import body_parameters, params_file
from sim_bridge.world import CLEARANCE_RANGE, SimWorld

BUDGET_S = 240.0        # the issue: one filter x one nominal over 200 worlds
CUTOFFS = (1.0, 2.0, 3.0)  # m
STRIDE = 10             # periods between compared filter steps
CHECK_RUNS = ((1, 'path'), (13, 'path'), (43, 'goal'), (260, 'goal'))  # (world, nominal)


def _cpu_seconds():
    """Return the CPU seconds of this process and its finished children."""
    own, children = (resource.getrusage(who) for who in (resource.RUSAGE_SELF,
                                                          resource.RUSAGE_CHILDREN))
    return own.ru_utime + own.ru_stime + children.ru_utime + children.ru_stime


def wall(worlds, barrier, nominal, jobs):
    """Time run_barn over ``worlds``; return the bench record and the runs' records."""
    load_before = os.getloadavg()[0]
    cpu, start = _cpu_seconds(), time.perf_counter()
    records, _ = run_barn(worlds, [(barrier, nominal)], jobs, progress=False)
    wall_s, cpu = time.perf_counter() - start, _cpu_seconds() - cpu
    runs = [r['wall_time_s'] for r in records]
    return {'bench': 'barn', 'case': 'wall', 'filter': barrier, 'nominal': nominal,
            'worlds': len(worlds), 'jobs': jobs, 'cpu_count': os.cpu_count(),
            'wall_time_s': round(wall_s, 1), 'budget_s': BUDGET_S,
            'budget_for_these_worlds_s': round(BUDGET_S * len(worlds) / 200, 1),
            'cpu_s': round(cpu, 1),
            'sim_time_s': round(sum(r['time_s'] for r in records), 1),
            'run_loop_wall_p50_s': round(float(np.median(runs)), 2),
            'run_loop_wall_max_s': round(max(runs), 2),
            'load_before': round(load_before, 2), 'load_after': round(os.getloadavg()[0], 2),
            'success': sum(r['success'] for r in records),
            'collision': sum(r['collision'] for r in records),
            'deadlock': sum(r['deadlock'] for r in records),
            'timeout': sum(r['timeout'] for r in records)}, records


def _filter(scenario, barrier, period):
    """Return the CommandFilter the in-process loop builds for the world's base."""
    spec = scenario.robot(ROBOT_NAME)
    parameters = {**load_parameters([params_file(spec.type)], (), spec.name),
                  'rate': 1.0 / period, **body_parameters(spec), 'filter.barrier': barrier}
    return build_filter(parameters).command_filter


def _obstacles(scenario):
    """Return the cylinders as the loop gives them to the filter: Obstacles and their centres."""
    obstacles = [Obstacle(polygon=o.polygon, z_min=o.z[0], z_max=o.z[1])
                 for o in scenario.obstacles]
    return obstacles, np.array([o.polygon.mean(axis=0) for o in scenario.obstacles])


def _step_us(command_filter, state, obstacles, nominal):
    """Return (safe command, step time [us]) of one filter step."""
    start = time.perf_counter()
    command, _ = command_filter.filter(state, float(state[2]), nominal, obstacles)
    return command, (time.perf_counter() - start) * 1e6


def geometry(worlds, barrier, nominal):
    """Return the lazy-body record and one cut-off record per distance in CUTOFFS."""
    made, cylinders, build_ms = [], [], []
    compared = {cutoff: {'changed': 0, 'max_dv': 0.0, 'us': []} for cutoff in CUTOFFS}
    all_us, steps = [], 0
    for world in worlds:
        scenario = world.scenario()
        start = time.perf_counter()
        with SimWorld(scenario):
            build_ms.append((time.perf_counter() - start) * 1e3)
        run = run_in_process(scenario, barrier, nominal=nominal, until=BarnReferee())
        trace = run.robots[ROBOT_NAME]
        cylinders.append(len(scenario.obstacles))
        made.append(_bodies_reached(scenario, trace))
        obstacles, centres = _obstacles(scenario)
        every = ObstacleSet.from_obstacles(obstacles)
        full, cut = _filter(scenario, barrier, run.period), _filter(scenario, barrier,
                                                                      run.period)
        for k in range(0, len(trace.times), STRIDE):
            state, nominal_command = trace.states[k], trace.nominal[k]
            reference, elapsed = _step_us(full, state, every, nominal_command)
            all_us.append(elapsed)
            steps += 1
            distance = np.hypot(*(centres - state[:2]).T)
            for cutoff, tally in compared.items():
                near = ObstacleSet.from_obstacles(
                    [o for o, d in zip(obstacles, distance) if d <= cutoff])
                command, elapsed = _step_us(cut, state, near, nominal_command)
                tally['us'].append(elapsed)
                change = float(np.max(np.abs(command - reference)))
                tally['changed'] += change > 1e-9
                tally['max_dv'] = max(tally['max_dv'], change)
    records = [{'bench': 'barn', 'case': 'lazy_bodies', 'worlds': len(worlds),
                'cylinders_mean': round(float(np.mean(cylinders)), 1),
                'bodies_made_at_most_mean': round(float(np.mean(made)), 1),
                'body_ms': round(body_ms(), 3),
                'world_build_ms_p50': round(float(np.median(build_ms)), 1)}]
    for cutoff, tally in compared.items():
        records.append({
            'bench': 'barn', 'case': 'distance_cutoff', 'filter': barrier, 'nominal': nominal,
            'cutoff_m': cutoff, 'worlds': len(worlds), 'steps_compared': steps,
            'steps_changed_frac': round(tally['changed'] / steps, 4),
            'max_command_change': round(tally['max_dv'], 4),
            'step_p50_us_all': round(float(np.median(all_us)), 1),
            'step_p50_us_cut': round(float(np.median(tally['us'])), 1)})
    return records


def _bodies_reached(scenario, trace):
    """Return how many cylinders' boxes came within CLEARANCE_RANGE of the disc's reach.

    The disc's reach from its base is its radius times sqrt(2) (a corner of its box).
    """
    positions = trace.positions()[:, None, :]
    lower = np.array([o.polygon.min(axis=0) for o in scenario.obstacles])
    upper = np.array([o.polygon.max(axis=0) for o in scenario.obstacles])
    gaps = np.maximum(np.maximum(lower - positions, positions - upper), 0.0)
    reach = scenario.robot(ROBOT_NAME).radius * np.sqrt(2.0)
    return int(np.sum(np.min(np.hypot(gaps[..., 0], gaps[..., 1]), axis=0) - reach
                      <= CLEARANCE_RANGE))


def body_ms(count=200):
    """Return the time [ms] PyBullet takes to make one cylinder body (mean of ``count``)."""
    client = pb.connect(pb.DIRECT)
    try:
        shape = pb.createCollisionShape(pb.GEOM_CYLINDER, radius=0.075, height=1.0,
                                        physicsClientId=client)
        start = time.perf_counter()
        for i in range(count):
            pb.createMultiBody(0.0, shape, basePosition=(0.2 * i, 0.0, 0.5),
                               physicsClientId=client)
        return (time.perf_counter() - start) * 1e3 / count
    finally:
        pb.disconnect(physicsClientId=client)


def barrier_check_cost(barrier, rounds):
    """Return one record per ``braking_check_barrier`` setting over ``CHECK_RUNS``."""
    by_id = {world.world: world for world in load_worlds(WORLDS_FILE)}
    runs = {True: [], False: []}
    for _ in range(rounds):
        for setting, records in runs.items():
            for number, nominal in CHECK_RUNS:
                (record, _), = run_world(by_id[number], [(barrier, nominal)], parameters={
                    'filter.braking_check_barrier': setting})
                records.append(record)
    return [{'bench': 'barn', 'case': 'braking_check_barrier', 'filter': barrier,
             'barrier_test': setting, 'runs': [list(run) for run in CHECK_RUNS],
             'rounds': rounds,
             'step_p50_us': round(float(np.median([r['latency_p50_us'] for r in records])), 1),
             'step_p99_us': round(float(np.median([r['latency_p99_us'] for r in records])), 1),
             'success': sum(r['success'] for r in records) // rounds,
             'runs_with_negative_h': sum(r['deepest_h'] < 0 for r in records) // rounds,
             'load_after': round(os.getloadavg()[0], 2)}
            for setting, records in runs.items()]


def stalls(worlds, records, barrier, nominal, count):
    """Return a record per deadlocked run (the first ``count``): the filter at its end."""
    by_id = {world.world: world for world in worlds}
    results = []
    for record in [r for r in records if r['deadlock']][:count]:
        world = by_id[record['world']]
        scenario = world.scenario()
        run = run_in_process(scenario, barrier, nominal=nominal, until=BarnReferee())
        trace = run.robots[ROBOT_NAME]
        command_filter = _filter(scenario, barrier, run.period)
        obstacles, centres = _obstacles(scenario)
        state, nominal_command = trace.states[-1], trace.nominal[-1]
        command, info = command_filter.filter(state, float(state[2]), nominal_command,
                                              ObstacleSet.from_obstacles(obstacles))
        gaps = (np.hypot(*(centres - state[:2]).T) - world.cylinder_radius
                - scenario.robot(ROBOT_NAME).radius)
        config = command_filter.safety_filter.config
        recent = collections.Counter(trace.statuses[-round(STOP_TIME / run.period):])
        results.append({
            'bench': 'barn', 'case': 'stall', 'filter': barrier, 'nominal': nominal,
            'world': world.world, 'time_s': record['time_s'], 'status': info.status.value,
            'speed': round(float(state[3]), 4),
            'nominal_speed': round(float(nominal_command[0]), 3),
            'safe_speed': round(float(command[0]), 4), 'active_rows': len(info.active),
            'active_gaps_m': [round(float(gaps[i]), 3) for i in info.active],
            'nearest_gap_m': round(float(gaps.min()), 3), 'min_h': round(float(info.min_h), 5),
            'margin_over_gamma': round(config.margin / config.gamma, 5),
            'recent_statuses': dict(recent)})
    return results


def main(argv=None):
    """Run both measurements, print them and write the JSON records."""
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument('--filter', default='default')
    parser.add_argument('--nominal', default='path', choices=('path', 'goal'))
    parser.add_argument('--jobs', type=int, default=os.cpu_count())
    parser.add_argument('--limit', type=int, default=None, help='only the first K worlds')
    parser.add_argument('--geometry-worlds', type=int, default=10)
    parser.add_argument('--stalls', type=int, default=8)
    parser.add_argument('--check-rounds', type=int, default=3,
                        help='rounds of the braking check comparison (0: skip it)')
    parser.add_argument('--out', default='bench/results/barn.json')
    args = parser.parse_args(argv)
    require_installed_checkout()
    worlds = load_worlds(WORLDS_FILE)[:args.limit]
    (barrier,) = resolve_filters([args.filter], 'diff_drive')
    record, runs = wall(worlds, barrier, args.nominal, args.jobs)
    print(f'{"filter":<18} {"nominal":<8} {"worlds":>6} {"jobs":>4} {"wall s":>7} '
          f'{"budget s":>8} {"CPU s":>6} {"sim s":>7} {"load":>9} {"success":>7}')
    print(f'{barrier:<18} {args.nominal:<8} {record["worlds"]:>6} {args.jobs:>4} '
          f'{record["wall_time_s"]:>7.0f} {record["budget_for_these_worlds_s"]:>8.0f} '
          f'{record["cpu_s"]:>6.0f} {record["sim_time_s"]:>7.0f} '
          f'{record["load_before"]:>4.1f}/{record["load_after"]:<4.1f} '
          f'{record["success"]:>7}', flush=True)
    records = [record]
    if args.geometry_worlds:
        extra = geometry(worlds[:args.geometry_worlds], barrier, args.nominal)
        lazy = extra[0]
        print('\nPyBullet bodies made on first use: at most '
              f'{lazy["bodies_made_at_most_mean"]:.0f} of {lazy["cylinders_mean"]:.0f} '
              'cylinders per run (a body costs '
              f'{lazy["body_ms"]:.2f} ms); world built in {lazy["world_build_ms_p50"]:.0f} ms '
              '(p50)')
        print(f'\n{"cut-off m":>9} {"steps":>6} {"changed":>8} {"max |dv|":>9} '
              f'{"step us all":>12} {"step us cut":>12}')
        for cut in extra[1:]:
            print(f'{cut["cutoff_m"]:>9.1f} {cut["steps_compared"]:>6} '
                  f'{cut["steps_changed_frac"]:>8.1%} {cut["max_command_change"]:>9.3f} '
                  f'{cut["step_p50_us_all"]:>12.0f} {cut["step_p50_us_cut"]:>12.0f}')
        records += extra
    if args.check_rounds:
        compared = barrier_check_cost(barrier, args.check_rounds)
        print(f'\n{"braking check":<22} {"step p50 us":>11} {"step p99 us":>11} '
              f'{"success":>7} {"runs h<0":>8}')
        for row in compared:
            label = 'clearance and barrier' if row['barrier_test'] else 'clearance only'
            print(f'{label:<22} {row["step_p50_us"]:>11.0f} {row["step_p99_us"]:>11.0f} '
                  f'{row["success"]:>4}/{len(CHECK_RUNS):<2} '
                  f'{row["runs_with_negative_h"]:>8}')
        records += compared
    if args.stalls:
        found = stalls(worlds, runs, barrier, args.nominal, args.stalls)
        print(f'\n{"world":>5} {"t s":>6} {"status":>7} {"v":>7} {"v nom":>6} {"v safe":>7} '
              f'{"active gaps m":>14} {"nearest m":>9} {"min h":>8} {"m/gamma":>8}')
        for stall in found:
            gaps = ' '.join(f'{g:.3f}' for g in stall['active_gaps_m']) or '-'
            print(f'{stall["world"]:>5} {stall["time_s"]:>6.1f} {stall["status"]:>7} '
                  f'{stall["speed"]:>7.4f} {stall["nominal_speed"]:>6.2f} '
                  f'{stall["safe_speed"]:>7.4f} {gaps:>14} {stall["nearest_gap_m"]:>9.3f} '
                  f'{stall["min_h"]:>8.5f} {stall["margin_over_gamma"]:>8.5f}')
        records += found
    write_records(records, args.out)
    return records


if __name__ == '__main__':
    main()
