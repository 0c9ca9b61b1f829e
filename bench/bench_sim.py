"""Benchmark the PyBullet world alone, and in-process closed loop: real-time factor, memory.

Usage: python bench/bench_sim.py [--seconds S] [--case NAME] [--repeats R]
       [--barrier NAME] [--out bench/results/sim.json]

Per physics step: ``SimWorld.step()``.  Per control period, per robot, what the
bridge node will do besides ROS: read the state, compute the nominal command
(the open-loop reference controllers, no safety filter), hold it, build the
obstacle footprints to publish, and sample the metrics (closest points).
real_time_factor = simulated time / wall time; cpu_real_time_factor uses the
process CPU time, the fairer number on a shared machine.  rss_mb is the peak
resident set of the process so far (cases run grouped as tabled: the A1s first).

Closed loop in process (``closed_loop: true``, ``transport: in_process``): the
same cases through ``sim_bridge.closed_loop.run_in_process``, the evaluation's
lockstep runner: per period and robot the nominal law, the node's
``CommandFilter`` and the world, with no DDS in between.  The filter is the
robot type's shipped parameter file with its default barrier
(``launcher.default_barrier``, what ``evaluate --filters default`` and the DDS
loop run), or ``--barrier``.  It shows what the simulation plus the filter cost;
the loop over DDS with one process per node is ``bench_sim_closed_loop.py``.

Like with like: every record names the robot type (``robot_type``: ``quadruped``
is the A1), the filter's ``model`` and the ``control_rate`` [Hz] (the A1s run at
120 Hz, the Crazyflie at 500 Hz, four times the periods per simulated second), and
the tables put each robot type and rate apart: the Crazyflie rows are not read
against the A1 goals.  Goals in process (``goal_real_time_factor``,
``goal_met``): 1 A1 >= 30x, 8 A1 >= 10x real time.

Every case runs ``--repeats`` times (default 3): on a shared 2-core VM one run's
speed varies by up to ~1.5x (the filter's own p50 with it).  A record is the run
with the median real-time factor, with every run's factor in
``real_time_factor_runs``; the table shows the median and the range.
"""
import argparse
import dataclasses
import resource
import time

import numpy as np
from bench_io import require_installed_checkout, write_records

from polyc2bf_ros.core.kernels import jit
from polyc2bf_ros.core.models import crazyflie as cf
from sim_bridge.closed_loop import run_in_process
from sim_bridge.launcher import BARRIERS, default_barrier
from sim_bridge.metrics import RunMetrics
from sim_bridge.nominal import QuadrotorGoalController, UnicycleGoalController
from sim_bridge.robots import robot_type
from sim_bridge.scenario import load_scenario, scenario_from_dict
from sim_bridge.world import SimWorld


def quadruped_50_obstacles():
    """Return one A1 crossing 50 seeded random polygons."""
    return scenario_from_dict({
        'name': 'quadruped_50_obstacles', 'duration': 30.0, 'seed': 7,
        'robots': [{'name': 'a1', 'type': 'quadruped', 'start': [0, 0, 0], 'goal': [20, 0]}],
        'random_obstacles': {'count': 50, 'region': [[2, -8], [18, 8]], 'size': [0.4, 1.0],
                             'height': [0.5, 1.5], 'clearance': 1.0, 'spacing': 0.9}})


def crazyflie_pillars():
    """Return the quadrotor_pillars scenario with a goal the open-loop flight reaches."""
    scenario = load_scenario('quadrotor_pillars')
    robot = dataclasses.replace(scenario.robots[0], goal=np.array([8.0, 1.2, 1.0]))
    return dataclasses.replace(scenario, name='crazyflie_pillars', robots=(robot,))


def quadrupeds_8():
    """Return eight A1s walking abreast in lanes 1.5 m apart (each in range of two)."""
    robots = [{'name': f'a1_{i}', 'type': 'quadruped', 'start': [0.0, 1.5 * i, 0.0],
               'goal': [20.0, 1.5 * i]} for i in range(8)]
    return scenario_from_dict({'name': 'quadrupeds_8', 'duration': 30.0, 'robots': robots})


def quadrupeds_8_crossing():
    """Return eight A1s on a 6 m circle driving through each other to the far side.

    The worst case for clearances: with no filter all eight overlap mid-way,
    and every close A1 pair costs a full link-pair query.
    """
    angles = np.arange(8) * np.pi / 4
    robots = [{'name': f'a1_{i}', 'type': 'quadruped',
               'start': [6 * np.cos(a), 6 * np.sin(a), a + np.pi],
               'goal': [-6 * np.cos(a), -6 * np.sin(a)]} for i, a in enumerate(angles)]
    return scenario_from_dict({'name': 'quadrupeds_8_crossing', 'duration': 30.0,
                               'robots': robots})


CASES = {'quadruped_50_obstacles': quadruped_50_obstacles,
         'crazyflie_pillars': crazyflie_pillars, 'quadrupeds_8': quadrupeds_8,
         'quadrupeds_8_crossing': quadrupeds_8_crossing}
# Real-time factor goals of the closed loop in process, by (robot type, robot count).
GOALS = {('quadruped', 1): 30.0, ('quadruped', 8): 10.0}
LABELS = {'quadruped': 'A1', 'crazyflie': 'Crazyflie', 'diff_drive': 'diff drive'}
KERNELS = 'ahead_of_time' if jit.AHEAD_OF_TIME is not None else 'just_in_time'


def describe(scenario):
    """Return {robot_type, model, control_rate, robots} of a scenario (one robot type)."""
    types = sorted({robot.type for robot in scenario.robots})
    if len(types) != 1:
        raise ValueError(f'{scenario.name}: one robot type per case, got {types}')
    return {'robot_type': types[0], 'model': robot_type(types[0]).model,
            'control_rate': float(scenario.effective_control_rate),
            'robots': len(scenario.robots)}


def groups(cases):
    """Return [((robot type, control rate), [case, ...])], A1 groups first, in case order."""
    found = {}
    for name in cases:
        info = describe(CASES[name]())
        found.setdefault((info['robot_type'], info['control_rate']), []).append(name)
    return sorted(found.items(), key=lambda item: item[0][0] != 'quadruped')


def _group_title(key):
    """Return e.g. 'A1 (quadruped, unicycle model), 120 Hz control'."""
    kind, rate = key
    return (f'{LABELS.get(kind, kind)} ({kind}, {robot_type(kind).model} model), '
            f'{rate:g} Hz control')


def _controller(world, robot):
    """Return a closure that holds the reference controller's command for ``robot``."""
    spec = world.robot_spec(robot)
    if spec.type == 'quadruped':
        controller = UnicycleGoalController()
        return lambda: world.set_command(
            robot, controller.velocity_command(world.robot_state(robot), spec.goal))
    controller = QuadrotorGoalController()
    return lambda: world.set_command(
        robot, np.clip(controller(world.robot_state(robot), spec.goal), 0.0,
                       cf.MAX_ROTOR_THRUST))


def run_case(name, seconds):
    """Simulate ``seconds`` of case ``name``; return its result record."""
    start = time.perf_counter()
    scenario = CASES[name]()
    world = SimWorld(scenario)
    build_s = time.perf_counter() - start
    metrics = RunMetrics(world)
    controls = [_controller(world, robot) for robot in world.robot_names]
    for control in controls:
        control()  # warm-up outside the timing: core functions may be JIT-compiled on first call
    steps_per_control = scenario.physics_rate / scenario.control_rate
    steps = int(round(seconds * scenario.physics_rate))
    published = 0
    physics_s = 0.0
    wall, cpu = time.perf_counter(), time.process_time()
    next_control = 0.0
    for step in range(steps):
        if step >= next_control:
            next_control += steps_per_control
            for robot, control in zip(world.robot_names, controls):
                control()
                published += len(world.obstacle_footprints(robot))
            metrics.update()
        tick = time.perf_counter()
        world.step()
        physics_s += time.perf_counter() - tick
    wall, cpu = time.perf_counter() - wall, time.process_time() - cpu
    collisions = sum(m.collision for m in metrics.robots.values())
    world.close()
    return {'bench': 'sim', 'case': name, **describe(scenario),
            'obstacles': len(scenario.all_obstacles()), 'closed_loop': False,
            'real_time_factor': round(seconds / wall, 2),
            'cpu_real_time_factor': round(seconds / cpu, 2),
            'physics_share': round(physics_s / wall, 3),
            'rss_mb': round(resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024, 1),
            'sim_seconds': seconds, 'physics_rate': scenario.physics_rate,
            'build_s': round(build_s, 2),
            'footprints_per_s': round(published / wall), 'robots_collided': collisions}


def run_closed_loop_case(name, seconds, barrier='default'):
    """Run case ``name`` in closed loop in this process; return its result record.

    ``barrier`` 'default': the robot type's (``launcher.default_barrier``).
    """
    scenario = CASES[name]()
    info = describe(scenario)
    if barrier == 'default':
        barrier = default_barrier(info['robot_type'])
    run = run_in_process(scenario, barrier, duration=seconds)
    statuses = [s for trace in run.robots.values() for s in trace.statuses]
    latency_us = np.concatenate([trace.latency_s for trace in run.robots.values()]) * 1e6
    factor = round(seconds / run.wall_time_s, 2)
    goal = GOALS.get((info['robot_type'], info['robots']))
    return {'bench': 'sim', 'case': name, **info, 'closed_loop': True,
            'transport': 'in_process', 'barrier': run.barrier,
            'real_time_factor': factor,
            'goal_real_time_factor': goal, 'goal_met': None if goal is None else factor >= goal,
            'rss_mb': round(resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024, 1),
            'sim_seconds': seconds, 'kernels': KERNELS,
            'filter_p50_us': round(float(np.nanpercentile(latency_us, 50)), 1),
            'filter_p99_us': round(float(np.nanpercentile(latency_us, 99)), 1),
            'non_ok_steps': sum(s != 'ok' for s in statuses),
            'robots_collided': sum(r['collision'] for r in run.metrics.values())}


def repeated(run, repeats):
    """Return the record of the median-speed run of ``run()``, with every run's factor."""
    records = sorted((run() for _ in range(repeats)), key=lambda r: r['real_time_factor'])
    record = records[len(records) // 2]
    record['real_time_factor_runs'] = [r['real_time_factor'] for r in records]
    return record


def _factors(record):
    """Return 'median (min-max)' of the record's real-time factors."""
    runs = record['real_time_factor_runs']
    return f'{record["real_time_factor"]:.1f} ({runs[0]:.1f}-{runs[-1]:.1f})'


def _table(title, header, grouped, run, repeats, cells):
    """Run ``run(case)`` ``repeats`` times per case; print a table per group; return the records.

    ``grouped``: ``groups()``, one table per robot type and control rate.
    """
    records = []
    for key, cases in grouped:
        print(f'{title}: {_group_title(key)}\n'
              f'{"case":<24} {"robots":>6} {"RTF wall (range)":>18} {header}')
        for name in cases:
            record = repeated(lambda: run(name), repeats)
            records.append(record)
            print(f'{name:<24} {record["robots"]:>6} {_factors(record):>18} {cells(record)}',
                  flush=True)
    return records


def _goal_cell(record):
    """Return the goal column of a closed-loop record: '>= 30x met', or '-' without a goal."""
    goal = record['goal_real_time_factor']
    if goal is None:
        return f'{"-":>14}'
    return f'{f">= {goal:g}x " + ("met" if record["goal_met"] else "NOT met"):>14}'


def main(argv=None):
    """Run every case, print a table and write the JSON records."""
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument('--seconds', type=float, default=20.0, help='simulated time per case')
    parser.add_argument('--case', choices=sorted(CASES), action='append',
                        help='run only this case (repeatable)')
    parser.add_argument('--repeats', type=int, default=3, choices=range(1, 11),
                        metavar='1..10', help='runs per case; the median is reported')
    parser.add_argument('--barrier', default='default', choices=('default',) + BARRIERS,
                        help="the closed loop's filter.barrier (default: the robot type's, "
                             'as its parameter file and launcher.default_barrier give it)')
    parser.add_argument('--out', default='bench/results/sim.json')
    args = parser.parse_args(argv)
    require_installed_checkout()
    grouped = groups(args.case or list(CASES))
    print(f'kernels {KERNELS}; the A1 and the Crazyflie run at different control rates: '
          'each robot type and rate has its own table')
    records = _table('world alone', f'{"RTF cpu":>8} {"physics":>8} {"RSS MB":>7} {"build s":>8}',
                     grouped, lambda name: run_case(name, args.seconds), args.repeats,
                     lambda r: (f'{r["cpu_real_time_factor"]:>8.1f} {r["physics_share"]:>8.0%} '
                                f'{r["rss_mb"]:>7.0f} {r["build_s"]:>8.2f}'))
    records += _table('\nclosed loop in process (nominal law + CommandFilter + world, no DDS)',
                      f'{"goal":>14} {"barrier":>17} {"filter p50 us":>14} {"p99 us":>8} '
                      f'{"non-ok":>7} {"RSS MB":>7}', grouped,
                      lambda name: run_closed_loop_case(name, args.seconds, args.barrier),
                      args.repeats,
                      lambda r: (f'{_goal_cell(r)} {r["barrier"]:>17} '
                                 f'{r["filter_p50_us"]:>14.0f} {r["filter_p99_us"]:>8.0f} '
                                 f'{r["non_ok_steps"]:>7} {r["rss_mb"]:>7.0f}'))
    write_records(records, args.out)
    return records


if __name__ == '__main__':
    main()
