"""``evaluate --suite dynamic``: the moving-cylinder worlds x filter x nominal, in parallel.

The worlds are ``sim_bridge.dynamic_worlds``' 60 generated courses (DynaBARN's
specification: 20 easy, 20 medium, 20 hard; a 0.2 m diff-drive disc crossing 20 m while
0.5 m cylinders circle on smooth loops).  Each run is ``closed_loop.run_in_process`` on
the world's Scenario with the ``goal`` (default) or ``path`` nominal (a straight
reference path from start to goal) and ``dynamic_worlds.ContactReferee`` ending it at
the first contact, at the goal (1 m) or after 60 s.  With ``obstacle_source`` 'markers'
the filter gets the cylinders as the bridge publishes them, through the node's own
obstacle pipeline (``run_in_process(marker_pipeline=True)``): the velocities it uses are
the node's estimates from successive marker poses, never the true ones; with 'scan' the
robot carries the simulated lidar and its filter sees only the scans (the moving bodies
are in the lidar's ray scene).  A world's Scenario is built once and runs all its
filter x nominal combinations in one task; tasks go out over ``jobs`` processes (one
progress bar, counted in runs).

Per run (one record in ``results.json``), first the result keys: ``suite``
('dynamic'), ``world`` (its id), ``difficulty``, ``filter``, ``nominal``,
``obstacle_source``, ``success``, ``at_fault_contact``, ``passive_contact``, ``timeout``
(exactly one is true: ``outcome`` names it, ``success``, ``contact_at_fault``,
``contact_passive`` or ``timeout``), ``time_s`` (sim time when the run ended),
``min_clearance_m`` (the smallest gap |p - c| - r_cylinder - r_disc over the run's periods;
<= 0 at a contact), ``mean_intervention`` and ``fallback_rate`` (as in the scenario suite,
``evaluate.filter_statistics``; null for ``none``); extras: ``contact`` (null, or the
contact: ``kind``, ``time_s``, ``cylinder``, ``gap_m``, ``robot_toward_m_s`` (the robot's
velocity toward the cylinder's centre, > 0.05 m/s: at fault), ``cylinder_toward_m_s``,
both positions), ``cylinders``, ``cylinder_speed_m_s`` [min, max], ``generator_seed``,
``marker_pipeline``, ``final_position``, ``final_distance_m`` (to the goal),
``path_length_m``, latency, fallback steps, ``steps``, ``deadlock_detections``,
``deadlocked_at_end``, ``negative_h_rate``, ``deepest_h``, ``wall_time_s`` and ``lidar``.

``results.md``: per filter x nominal x obstacle source, a row per difficulty and one over
all worlds (counts of success, at-fault and passive contacts, timeouts; mean time of the
successes; the smallest clearance of the runs without contact and the mean of every run's
smallest clearance), the at-fault contacts listed, and the plots ``outcomes.png``
(outcome shares per difficulty) and ``trajectories.png`` (sample worlds: the cylinders'
loops and where they were at the run's end, each filter's path, contacts marked).
"""
import json
import math
import os
import re
import time
from datetime import datetime
from pathlib import Path

import numpy as np

from sim_bridge import plots
from sim_bridge.barn import ROBOT_NAME
from sim_bridge.closed_loop import run_in_process
from sim_bridge.dynamic_worlds import (
    AT_FAULT_SPEED,
    ContactReferee,
    DEFAULT_SEED,
    DIFFICULTIES,
    difficulty_of,
    dynamic_world,
    MAX_OBSTACLE_ACCEL,
    TIME_LIMIT,
    WORLDS_PER_DIFFICULTY,
)
from sim_bridge.evaluation.arguments import run_or_exit, world_suite_plan
from sim_bridge.evaluation.parallel_runs import run_worlds
from sim_bridge.evaluation.records import (
    filter_statistics,
    group_records,
    lidar_record,
    STEP_KEYS,
)
from sim_bridge.evaluation.reports import actuation_line, obstacle_sources, table_cell

DYNAMIC_KEYS = ('suite', 'world', 'difficulty', 'filter', 'nominal', 'obstacle_source',
                'success', 'at_fault_contact', 'passive_contact', 'timeout', 'time_s',
                'min_clearance_m', 'mean_intervention', 'fallback_rate')
OUTCOMES = ('success', 'contact_at_fault', 'contact_passive', 'timeout')
TRACE_PERIOD = 0.1      # s between the trajectory points kept for the plots
SAMPLES_PER_DIFFICULTY = 2  # worlds per difficulty drawn in trajectories.png
ALL = 'all'


def _round(value, digits=4):
    return None if value is None or not math.isfinite(value) else round(float(value), digits)


def dynamic_record(world, run, referee):
    """Return the result record of one run of ``world`` ended by ``referee`` (module docstring)."""
    outcome = run.ended or 'timeout'
    trace = run.robots[ROBOT_NAME]
    final = trace.positions()[-1]
    metrics = run.metrics[ROBOT_NAME]
    stats = filter_statistics(run)
    speeds = [c.speed for c in world.cylinders]
    return {
        'suite': 'dynamic', 'world': world.world, 'difficulty': world.difficulty,
        'filter': run.barrier, 'nominal': run.nominal, 'obstacle_source': run.obstacle_source,
        'success': outcome == 'success', 'at_fault_contact': outcome == 'contact_at_fault',
        'passive_contact': outcome == 'contact_passive', 'timeout': outcome == 'timeout',
        'time_s': _round(len(trace.times) * run.period, 3),
        'min_clearance_m': _round(referee.min_clearance),
        'mean_intervention': stats['mean_intervention'],
        'fallback_rate': stats['fallback_rate'],
        'outcome': outcome, 'contact': referee.contact,
        'cylinders': len(world.cylinders),
        'cylinder_speed_m_s': [_round(min(speeds), 3), _round(max(speeds), 3)],
        'generator_seed': world.seed, 'marker_pipeline': run.marker_pipeline,
        'final_position': [_round(value, 3) for value in final],
        'final_distance_m': _round(math.dist(final, referee.goal)),
        'path_length_m': metrics['path_length_m'],
        **{key: stats[key] for key in STEP_KEYS},
        'wall_time_s': round(run.wall_time_s, 2), 'lidar': lidar_record(run),
        'actuation': run.actuation.record(),
    }


def _trajectory(run, referee):
    """Return the positions every TRACE_PERIOD s (and the last), the end time and the contact."""
    positions = run.robots[ROBOT_NAME].positions()
    stride = max(1, round(TRACE_PERIOD / run.period))
    kept = np.vstack([positions[::stride], positions[-1:]]).astype(np.float32)
    return {'positions': kept, 'end_time': (len(positions) - 1) * run.period,
            'contact': referee.contact}


def run_world(world, combos, parameters=None, obstacle_source='markers', lidar=None,
              actuation=None):
    """Run ``world`` (DynamicWorld) with every (filter, nominal) of ``combos``.

    Return [(record, trajectory)] in ``combos`` order; the Scenario is built once.
    ``parameters``: node parameters that override the parameter file's;
    ``obstacle_source``, ``lidar``, ``actuation``: as for ``run_in_process`` (markers go
    through the node's obstacle pipeline).
    """
    scenario = world.scenario()
    results = []
    for barrier, nominal in combos:
        referee = ContactReferee(scenario)
        run = run_in_process(scenario, barrier, nominal=nominal, until=referee,
                             parameters=parameters, obstacle_source=obstacle_source,
                             lidar=lidar, marker_pipeline=obstacle_source == 'markers',
                             actuation=actuation)
        results.append((dynamic_record(world, run, referee), _trajectory(run, referee)))
    return results


def run_dynamic(worlds, combos, jobs=None, progress=True, parameters=None,
                obstacle_source='markers', lidar=None, actuation=None):
    """Run every world x combo over ``jobs`` processes (default: the CPU count).

    ``parameters``, ``obstacle_source``, ``lidar``, ``actuation``: as for ``run_world``.
    Return (records, trajectories) in world, then combo order; trajectories are keyed by
    (world id, filter, nominal).  With one job everything runs in this process.
    """
    return run_worlds(worlds, combos, run_world,
                      (parameters, obstacle_source, lidar, actuation), jobs, progress,
                      lambda world: f'world {world.world} ({world.difficulty})')


# -- tables and plots -----------------------------------------------------------------------

def aggregate_dynamic(records):
    """Return per (filter, nominal, source) a row per difficulty present, then one over all."""
    rows = []
    for (name, nominal, source), group in group_records(records, 'filter', 'nominal',
                                                         'obstacle_source').items():
        present = [d for d in DIFFICULTIES if any(r['difficulty'] == d for r in group)]
        for difficulty in present + [ALL]:
            mine = [r for r in group if difficulty in (ALL, r['difficulty'])]
            times = [r['time_s'] for r in mine if r['success']]
            free = [r['min_clearance_m'] for r in mine
                    if r['outcome'] in ('success', 'timeout') and r['min_clearance_m'] is not None]
            clearances = [r['min_clearance_m'] for r in mine if r['min_clearance_m'] is not None]
            interventions = [r['mean_intervention'] for r in mine
                             if r['mean_intervention'] is not None]
            fallbacks = [r['fallback_rate'] for r in mine if r['fallback_rate'] is not None]
            rows.append({
                'filter': name, 'nominal': nominal, 'obstacle_source': source,
                'difficulty': difficulty, 'runs': len(mine),
                **{outcome: sum(r['outcome'] == outcome for r in mine) for outcome in OUTCOMES},
                'mean_success_time_s': float(np.mean(times)) if times else None,
                'min_clearance_without_contact_m': min(free) if free else None,
                'mean_min_clearance_m': float(np.mean(clearances)) if clearances else None,
                'mean_intervention': float(np.mean(interventions)) if interventions else None,
                'fallback_rate': float(np.mean(fallbacks)) if fallbacks else None,
                'mean_wall_time_s': float(np.mean([r['wall_time_s'] for r in mine])),
            })
    return rows


def dynamic_table(rows):
    """Return the Markdown table of aggregated rows."""
    lines = ['| filter | nominal | obstacles | difficulty | worlds | success | at-fault contact | '
             'passive contact | timeout | time of successes [s] | '
             'min clearance, no contact [m] | mean min clearance [m] | mean intervention | '
             'fallback rate | wall time per run [s] |', '|' + '---|' * 15]
    for r in rows:
        n = r['runs']
        label = f'**{r["difficulty"]}**' if r['difficulty'] == ALL else r['difficulty']
        lines.append(
            f'| {r["filter"]} | {r["nominal"]} | {r["obstacle_source"]} | {label} | {n} | '
            f'{r["success"]}/{n} | {r["contact_at_fault"]}/{n} | {r["contact_passive"]}/{n} | '
            f'{r["timeout"]}/{n} | {table_cell(r["mean_success_time_s"], 1)} | '
            f'{table_cell(r["min_clearance_without_contact_m"], 3)} | '
            f'{table_cell(r["mean_min_clearance_m"], 3)} | '
            f'{table_cell(r["mean_intervention"], 3)} | {table_cell(r["fallback_rate"], 3)} | '
            f'{table_cell(r["mean_wall_time_s"], 1)} |')
    return '\n'.join(lines)


def contact_lines(records):
    """Return one line per at-fault contact: world, combo, time and the approach speeds."""
    lines = []
    for r in records:
        if r['outcome'] != 'contact_at_fault':
            continue
        c = r['contact']
        lines.append(f'- world {r["world"]} ({r["difficulty"]}), {r["filter"]} / {r["nominal"]} '
                     f'/ {r["obstacle_source"]}: {c["cylinder"]} at {c["time_s"]:.2f} s, robot '
                     f'{c["robot_toward_m_s"]:.2f} m/s toward it, cylinder '
                     f'{c["cylinder_toward_m_s"]:.2f} m/s toward the robot.')
    return lines


def sample_worlds(worlds, per_difficulty=SAMPLES_PER_DIFFICULTY):
    """Return up to ``per_difficulty`` worlds of each difficulty, spread over its ids."""
    chosen = []
    for difficulty in DIFFICULTIES:
        mine = [w for w in worlds if w.difficulty == difficulty]
        step = max(1, len(mine) // per_difficulty)
        chosen += mine[::step][:per_difficulty]
    return chosen


def write_dynamic_outputs(out, records, trajectories, worlds, command, wall_time_s, jobs,
                          plots_too=True):
    """Write results.json, results.md and (unless ``plots_too`` is False) the PNGs."""
    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    (out / 'results.json').write_text(json.dumps(records, indent=1) + '\n')
    rows = aggregate_dynamic(records)
    load = ', '.join(f'{v:.2f}' for v in os.getloadavg())
    seeds = ', '.join(str(s) for s in sorted({w.seed for w in worlds}))
    at_fault = contact_lines(records)
    text = ['# Evaluation: dynamic worlds (moving cylinders; lockstep, in-process, PyBullet)',
            '', f'Command: `{command}`  ',
            f'Date: {datetime.now().isoformat(timespec="seconds")}; wall time '
            f'{wall_time_s:.0f} s over {jobs} process(es) '
            f'({wall_time_s / max(len(records), 1):.1f} s per run); load average after the '
            f'run: {load}.  ',
            f"Obstacles: {obstacle_sources(records)} (markers: through the node's obstacle "
            'pipeline, with estimated velocities).  ',
            f'Actuation: {actuation_line(records)}.  ',
            f'{len(records)} runs over {len(worlds)} worlds (generator seed {seeds}); per run '
            'JSON in `results.json`.  Definitions: `sim_bridge/dynamic_worlds.py` and '
            '`sim_bridge/evaluation/dynamic_suite.py` docstrings.  A run ends at the first '
            f'contact (gap <= 0), at the goal (1 m) or after {TIME_LIMIT:g} s; a contact is at '
            f'fault when the robot moved toward the cylinder at more than {AT_FAULT_SPEED:g} m/s, '
            f'passive otherwise.  Cylinder loops need at most {MAX_OBSTACLE_ACCEL:g} m/s^2.',
            '', dynamic_table(rows), '']
    if at_fault:
        text += ['## At-fault contacts', '', *at_fault, '']
    if plots_too:
        text += ['![outcomes](outcomes.png)', '', '![trajectories](trajectories.png)', '']
    (out / 'results.md').write_text('\n'.join(text))
    if plots_too:
        combos = list(dict.fromkeys((r['filter'], r['nominal']) for r in records))
        plots.dynamic_outcomes_figure(out / 'outcomes.png', rows)
        plots.dynamic_trajectories_figure(out / 'trajectories.png', sample_worlds(worlds),
                                          trajectories, combos)
    return rows


_RANGE = re.compile(r'(\d+)(?:-(\d+))?\Z')


def parse_world_ids(tokens, count):
    """Return the sorted ids of ``tokens`` ('7', '0-19', '3,5,40-45'); ValueError if bad."""
    ids = set()
    for token in tokens:
        for part in filter(None, str(token).split(',')):
            match = _RANGE.match(part.strip())
            if match is None:
                raise ValueError(f'--worlds wants ids or ranges like 7 or 0-19, got {part!r}')
            low = int(match.group(1))
            high = int(match.group(2)) if match.group(2) is not None else low
            if low > high or high >= count:
                raise ValueError(f'--worlds {part}: ids run from 0 to {count - 1}')
            ids.update(range(low, high + 1))
    return sorted(ids)


def main_dynamic(parser, args, command):
    """``evaluate --suite dynamic``: run, write, print; exit 0, 2 on bad arguments, 130 on ^C."""
    if args.jobs is not None and args.jobs < 1:
        parser.error('--jobs must be >= 1')
    count = WORLDS_PER_DIFFICULTY * len(DIFFICULTIES)
    try:
        ids = parse_world_ids(args.worlds, count) if args.worlds else range(count)
    except ValueError as exc:
        parser.error(str(exc))
    difficulties = args.difficulty or list(DIFFICULTIES)
    ids = [i for i in ids if difficulty_of(i) in difficulties]
    if not ids:
        parser.error('no dynamic world matches --worlds and --difficulty')
    seed = DEFAULT_SEED if args.generator_seed is None else args.generator_seed
    worlds = [dynamic_world(i, seed) for i in ids]
    combos, jobs, settings = world_suite_plan(parser, args, 'goal')
    out = Path(args.out or 'runs/dynamic')
    start = time.monotonic()
    records, trajectories = run_or_exit(parser, run_dynamic, worlds, combos, jobs,
                                        **settings)
    write_dynamic_outputs(out, records, trajectories, worlds, command,
                          time.monotonic() - start, jobs, not args.no_plots)
    print(dynamic_table(aggregate_dynamic(records)))
    lines = contact_lines(records)
    if lines:
        print('\nAt-fault contacts:\n' + '\n'.join(lines))
    print(f'\nwrote {out / "results.json"}, results.md'
          + ('' if args.no_plots else ', outcomes.png, trajectories.png'))
    return 0
