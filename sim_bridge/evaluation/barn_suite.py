"""``evaluate --suite barn``: every BARN world x filter x nominal, in lockstep, in parallel.

Each run is ``closed_loop.run_in_process`` on the world's Scenario
(``sim_bridge.barn``: a 0.2 m diff-drive disc, or with ``--robot jackal`` the Jackal's
box, PyBullet closest points for collisions), with the ``goal`` or ``path`` nominal at
its default speed or ``--speed``, and ``BarnReferee`` ending it.  A world's Scenario is
built once and runs all its filter x nominal combinations in one task; tasks go out over
``jobs`` processes (one progress bar, counted in runs).

With ``obstacle_source`` 'scan' the robot carries the simulated lidar (the robot type's
own, ``RobotType.lidar``, with ``--lidar`` changes) and its filter sees only the scans
(``closed_loop``; ``evaluate --obstacle-source``).

Per run (one record in ``results.json``; the keys of doc/design.md, result records, first):
``suite`` ('barn'), ``world`` (its id), ``filter``, ``nominal``, ``obstacle_source``
(``markers`` or ``scan``; ``lidar``, the settings, among the extras), ``success``,
``collision``, ``timeout``, ``deadlock`` (exactly one of the last four is true:
``outcome`` names it), ``time_s`` (sim time when the run ended: at the goal for
a success), ``barn_metric`` (``barn.barn_metric``), ``min_clearance_m`` (null:
nothing came within 0.5 m), ``mean_intervention`` and ``fallback_rate`` as in
the scenario suite (``evaluate.filter_statistics``; null for ``none``); extras:
``optimal_time_s``, ``robot`` (its type), ``speed`` (the nominal's cruise speed, null:
its default), ``final_position`` [x, y], ``final_distance_m`` (to the
goal), ``final_gap_m`` (from the robot's radius to the nearest cylinder's surface at the
end, exact for the disc: |p - c| - r_cylinder - r_disc), ``path_length_m``,
latency, fallback steps, ``steps``, ``wall_time_s`` and the deadlock report's
``deadlock_detections`` and ``deadlocked_at_end`` (``evaluate.filter_statistics``).

``results.md``: one row per filter x nominal (rates over worlds, mean metric
with failures as 0) beside BARN's DWA baseline, and the plots
``outcomes.png`` (success / collision / deadlock / timeout rates),
``trajectories.png`` (sample worlds: cylinders, reference path, every
filter's path per nominal) and ``metric_histogram.png``.
"""
import json
import math
import os
import time
from datetime import datetime
from pathlib import Path

import numpy as np

from sim_bridge import plots
from sim_bridge.barn import (
    barn_metric,
    BarnError,
    BarnReferee,
    load_worlds,
    ROBOT_NAME,
    WORLDS_FILE,
)
from sim_bridge.closed_loop import run_in_process
from sim_bridge.evaluation.arguments import run_or_exit, world_suite_plan
from sim_bridge.evaluation.parallel_runs import run_worlds
from sim_bridge.evaluation.records import (
    filter_statistics,
    group_records,
    lidar_record,
    STEP_KEYS,
)
from sim_bridge.evaluation.reports import actuation_line, obstacle_sources, table_cell
from sim_bridge.world import CLEARANCE_RANGE

BARN_KEYS = ('suite', 'world', 'filter', 'nominal', 'obstacle_source', 'success', 'collision',
             'timeout', 'deadlock', 'time_s', 'barn_metric', 'min_clearance_m',
             'mean_intervention', 'fallback_rate')
OUTCOMES = ('success', 'collision', 'deadlock', 'timeout')
# BARN's DWA (move_base) over 50 worlds x 10 runs, from the benchmark's README.
DWA_BASELINE = {'success': 0.88, 'collision': 0.048, 'timeout': 0.072, 'barn_metric': 0.1693}
TRACE_PERIOD = 0.1      # s between the trajectory points kept for the plots
SAMPLE_WORLDS = 4       # worlds drawn in trajectories.png


def _round(value, digits=4):
    return None if value is None else round(float(value), digits)


def barn_record(world, run):
    """Return the result record of one BARN run (module docstring)."""
    outcome = run.ended or 'timeout'
    trace = run.robots[ROBOT_NAME]
    final = trace.positions()[-1]
    spec = run.scenario.robot(ROBOT_NAME)
    radius = spec.radius
    gaps = np.hypot(*(world.centers - final).T) - world.cylinder_radius - radius
    metrics = run.metrics[ROBOT_NAME]
    time_s = len(trace.times) * run.period
    success = outcome == 'success'
    stats = filter_statistics(run)
    return {
        'suite': 'barn', 'world': world.world, 'filter': run.barrier, 'nominal': run.nominal,
        'obstacle_source': run.obstacle_source, 'success': success,
        'collision': outcome == 'collision', 'timeout': outcome == 'timeout',
        'deadlock': outcome == 'deadlock',
        'time_s': _round(time_s, 3),
        'barn_metric': _round(barn_metric(success, time_s, world.optimal_time)),
        'min_clearance_m': metrics['min_clearance_m'],
        'mean_intervention': stats['mean_intervention'],
        'fallback_rate': stats['fallback_rate'],
        'outcome': outcome, 'optimal_time_s': _round(world.optimal_time, 3),
        'robot': spec.type, 'speed': spec.speed,
        'final_position': [_round(value, 3) for value in final],
        'final_distance_m': _round(math.dist(final, world.goal)),
        'final_gap_m': _round(gaps.min()) if len(gaps) else None,
        'path_length_m': metrics['path_length_m'],
        **{key: stats[key] for key in STEP_KEYS},
        'penetration_m': _round(max(0.0, -metrics['min_clearance_m']))
        if metrics['min_clearance_m'] is not None else None,
        'wall_time_s': round(run.wall_time_s, 2), 'lidar': lidar_record(run),
        'actuation': run.actuation.record(),
    }


def _trajectory(run):
    """Return the positions every TRACE_PERIOD s (and the last) and the collision point."""
    positions = run.robots[ROBOT_NAME].positions()
    stride = max(1, round(TRACE_PERIOD / run.period))
    kept = np.vstack([positions[::stride], positions[-1:]]).astype(np.float32)
    return {'positions': kept, 'collision': positions[-1] if run.ended == 'collision' else None}


def run_world(world, combos, parameters=None, obstacle_source='markers', lidar=None,
              actuation=None, robot='diff_drive', speed=None):
    """Run ``world`` (BarnWorld) with every (filter, nominal) of ``combos``.

    Return [(record, trajectory)] in ``combos`` order; the Scenario is built once.
    ``parameters``: node parameters that override the parameter file's;
    ``obstacle_source``, ``lidar``, ``actuation``: as for ``run_in_process``; ``robot``,
    ``speed``: as for ``BarnWorld.scenario``.
    """
    scenario = world.scenario(robot, speed)
    results = []
    for barrier, nominal in combos:
        run = run_in_process(scenario, barrier, nominal=nominal, until=BarnReferee(),
                             parameters=parameters, obstacle_source=obstacle_source,
                             lidar=lidar, actuation=actuation)
        results.append((barn_record(world, run), _trajectory(run)))
    return results


def run_barn(worlds, combos, jobs=None, progress=True, parameters=None,
             obstacle_source='markers', lidar=None, actuation=None, robot='diff_drive',
             speed=None):
    """Run every world x combo over ``jobs`` processes (default: the CPU count).

    ``parameters``, ``obstacle_source``, ``lidar``, ``actuation``, ``robot``, ``speed``: as
    for ``run_world``.

    Return (records, trajectories) in world, then combo order; trajectories are keyed
    by (world id, filter, nominal).  With one job everything runs in this process.
    """
    return run_worlds(worlds, combos, run_world,
                      (parameters, obstacle_source, lidar, actuation, robot, speed), jobs,
                      progress)


# -- tables and plots -----------------------------------------------------------------------

def aggregate_barn(records):
    """Return one row per (filter, nominal) in record order: rates over worlds and means."""
    rows = []
    for (name, nominal, source), group in group_records(records, 'filter', 'nominal',
                                                         'obstacle_source').items():
        successes = [r['time_s'] for r in group if r['success']]
        clearances = [r['min_clearance_m'] for r in group if r['min_clearance_m'] is not None]
        interventions = [r['mean_intervention'] for r in group
                         if r['mean_intervention'] is not None]
        fallbacks = [r['fallback_rate'] for r in group if r['fallback_rate'] is not None]
        negative = [r.get('negative_h_rate') for r in group
                    if r.get('negative_h_rate') is not None]
        row = {'filter': name, 'nominal': nominal, 'obstacle_source': source,
               'runs': len(group)}
        row.update({outcome: sum(r[outcome] for r in group) / len(group)
                    for outcome in OUTCOMES})
        row.update({
            'barn_metric': float(np.mean([r['barn_metric'] for r in group])),
            'mean_success_time_s': float(np.mean(successes)) if successes else None,
            'min_clearance_m': min(clearances) if clearances else None,
            'mean_intervention': float(np.mean(interventions)) if interventions else None,
            'fallback_rate': float(np.mean(fallbacks)) if fallbacks else None,
            'negative_h_rate': float(np.mean(negative)) if negative else None,
            'penetration_m': max((r.get('penetration_m') or 0.0) for r in group),
            'reported': sum(bool(r['deadlock_detections']) for r in group),
            'freed': sum(bool(r['deadlock_detections']) and r['success'] for r in group),
            'unflagged_stalls': sum((r['deadlock'] or r['timeout'])
                                    and not r['deadlocked_at_end'] for r in group),
        })
        rows.append(row)
    return rows


def barn_table(rows):
    """Return the Markdown table of aggregated rows, with BARN's DWA baseline last."""
    lines = ['| filter | nominal | obstacles | worlds | success | collision | deadlock | '
             'timeout | metric | time of successes [s] | min clearance [m] | '
             'mean intervention | fallback rate | h < 0 steps | deepest penetration [m] |',
             '|' + '---|' * 15]
    for r in rows:
        clearance = (f'> {CLEARANCE_RANGE:g}' if r['min_clearance_m'] is None
                     else f'{r["min_clearance_m"]:.3f}')
        lines.append(
            f'| {r["filter"]} | {r["nominal"]} | {r["obstacle_source"]} | {r["runs"]} | '
            f'{r["success"]:.3f} | '
            f'{r["collision"]:.3f} | {r["deadlock"]:.3f} | {r["timeout"]:.3f} | '
            f'{r["barn_metric"]:.3f} | {table_cell(r["mean_success_time_s"], 1)} | {clearance} | '
            f'{table_cell(r["mean_intervention"], 3)} | {table_cell(r["fallback_rate"], 3)} | '
            f'{table_cell(r["negative_h_rate"], 4)} | {r["penetration_m"]:.3f} |')
    base = DWA_BASELINE
    lines.append(f'| DWA (move_base, BARN) | – | – | 50 x 10 runs | {base["success"]:.3f} | '
                 f'{base["collision"]:.3f} | – | {base["timeout"]:.3f} | '
                 f'{base["barn_metric"]:.3f} | – | – | – | – | – | – |')
    return '\n'.join(lines)


def deadlock_lines(rows):
    """Return one line per row: deadlock reports, runs freed after one, unflagged stalls.

    With ``deadlock_resolution: circulate`` a run freed after a report is a resolution;
    without it, a report the robot then got out of by itself is a false detection.
    """
    lines = []
    for r in rows:
        if r['filter'] == 'none':
            continue
        lines.append(f'- {r["filter"]} / {r["nominal"]}: {r["reported"]} of {r["runs"]} runs '
                     f'had a deadlock report, {r["freed"]} of them then reached the goal; '
                     f'{r["unflagged_stalls"]} stalled runs ended without a report.')
    return lines


def write_barn_outputs(out, records, trajectories, worlds, command, wall_time_s, jobs,
                       plots_too=True, worlds_label=None):
    """Write results.json, results.md and (unless ``plots_too`` is False) the PNGs.

    ``worlds_label`` names the world file in results.md (default: the path it was read from).
    """
    worlds_label = worlds_label or worlds[0].source
    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    (out / 'results.json').write_text(json.dumps(records, indent=1) + '\n')
    rows = aggregate_barn(records)
    load = ', '.join(f'{v:.2f}' for v in os.getloadavg())
    text = ['# Evaluation: BARN worlds (lockstep, in-process, PyBullet)', '',
            f'Command: `{command}`  ',
            f'Date: {datetime.now().isoformat(timespec="seconds")}; wall time '
            f'{wall_time_s:.0f} s over {jobs} process(es); load average after the run: '
            f'{load}.  ',
            f'Obstacles: {obstacle_sources(records)}.  ',
            f'Actuation: {actuation_line(records)}.  ',
            f'{len(records)} runs over {len(worlds)} worlds (from `{worlds_label}`); '
            'per run JSON in `results.json`.  Definitions: `sim_bridge/barn.py` and '
            '`sim_bridge/evaluation/barn_suite.py` docstrings.  Rates are shares of the '
            "worlds; the metric is BARN's (failures count 0, at most 0.5); DWA is BARN's "
            'published baseline, not run here.',
            '', barn_table(rows), '', *deadlock_lines(rows), '']
    if plots_too:
        text += ['![outcomes](outcomes.png)', '', '![trajectories](trajectories.png)', '',
                 '![metric histogram](metric_histogram.png)', '']
    (out / 'results.md').write_text('\n'.join(text))
    if plots_too:
        combos = [(r['filter'], r['nominal']) for r in rows]
        plots.barn_outcomes_figure(out / 'outcomes.png', rows, DWA_BASELINE)
        step = max(1, len(worlds) // SAMPLE_WORLDS)
        plots.barn_trajectories_figure(out / 'trajectories.png', worlds[::step][:SAMPLE_WORLDS],
                                       trajectories, combos)
        plots.barn_metric_figure(out / 'metric_histogram.png', records, combos,
                                 DWA_BASELINE['barn_metric'])
    return rows


def main_barn(parser, args, command):
    """``evaluate --suite barn``: run, write and print; exit 0, 2 on bad arguments, 130 on ^C."""
    for option in ('jobs', 'limit'):
        if getattr(args, option) is not None and getattr(args, option) < 1:
            parser.error(f'--{option} must be >= 1')
    label = args.worlds or 'bench/data/barn/barn_worlds.json (shipped)'
    try:
        worlds = load_worlds(args.worlds or WORLDS_FILE)[:args.limit]
    except BarnError as exc:
        parser.error(str(exc))
    robot = args.robot or 'diff_drive'
    if args.speed is not None and not 0.0 < args.speed <= 10.0:
        parser.error(f'--speed must be in (0, 10] m/s, got {args.speed:g}')
    combos, jobs, settings = world_suite_plan(parser, args, 'path', robot)
    settings.update(robot=robot, speed=args.speed)
    out = Path(args.out or 'runs/barn')
    start = time.monotonic()
    records, trajectories = run_or_exit(parser, run_barn, worlds, combos, jobs, **settings)
    rows = write_barn_outputs(out, records, trajectories, worlds, command,
                              time.monotonic() - start, jobs, not args.no_plots, label)
    print(barn_table(rows))
    print('\n'.join(['', *deadlock_lines(rows)]))
    print(f'\nwrote {out / "results.json"}, results.md'
          + ('' if args.no_plots else ', outcomes.png, trajectories.png, metric_histogram.png'))
    return 0
