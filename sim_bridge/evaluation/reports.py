"""What a suite's records become: the markdown table, findings and files in ``--out``.

``write_outputs`` writes ``results.json``, ``results.md`` and the plots of the scenario
suite; ``table_cell``, ``obstacle_sources`` and ``actuation_line`` are shared with the BARN
and dynamic suites' own tables.
"""
import json
import os
from datetime import datetime
from pathlib import Path

from sim_bridge import plots
from sim_bridge.actuation import describe as describe_actuation
from sim_bridge.evaluation.records import aggregate
from sim_bridge.world import CLEARANCE_RANGE

GRAZE = 0.01          # m: clearances below this are reported as near-contacts


POLYC2BF = ('polyc2bf_paper', 'polyc2bf_inflated')


PAPER_CLAIM = ('long_wall', 'semi_infinite_wall')  # where the paper says C3BF fails


def table_cell(value, digits=2, suffix=''):
    """Return ``value`` for a Markdown table: ``digits`` decimals and ``suffix``, '–' if None."""
    return '–' if value is None else f'{value:.{digits}f}{suffix}'


def markdown_table(rows):
    """Return the Markdown table of aggregated rows."""
    lines = ['| scenario | filter | obstacles | success | collision | deadlock | timeout | '
             'no cone at t=0 | min clearance [m] | time to goal ratio | mean intervention | '
             'fallback rate | h < 0 steps | latency p50 / p99 [us] |', '|' + '---|' * 14]
    for r in rows:
        n = r['runs']
        clearance = (f'> {CLEARANCE_RANGE:g}' if r['min_clearance_m'] is None
                     else f'{r["min_clearance_m"]:.3f}')
        latency = ('–' if r['latency_p50_us'] is None
                   else f'{r["latency_p50_us"]:.0f} / {r["latency_p99_us"]:.0f}')
        fallback = None if r['fallback_rate'] is None else 100 * r['fallback_rate']
        negative = None if r['negative_h_rate'] is None else 100 * r['negative_h_rate']
        lines.append(
            f'| {r["scenario"]} | {r["filter"]} | {r["obstacle_source"]} | '
            f'{r["success"]}/{n} | {r["collision"]}/{n} | '
            f'{r["deadlock"]}/{n} | {r["timeout"]}/{n} | {r["fallback_at_start"]}/{n} | '
            f'{clearance} | '
            f'{table_cell(r["time_to_goal_ratio"])} | {table_cell(r["mean_intervention"], 3)} | '
            f'{table_cell(fallback, 1, " %")} | {table_cell(negative, 2, " %")} | {latency} |')
    return '\n'.join(lines)


def findings(records, rows):
    """Return a list of one-line findings drawn from the measured records."""
    lines = []
    scenarios = list(dict.fromkeys(r['scenario'] for r in records))
    filters = list(dict.fromkeys(r['filter'] for r in records))
    for name in [f for f in POLYC2BF if f in filters]:
        mine = [r for r in records if r['filter'] == name]
        hits = sorted({f'{r["scenario"]} (seed {r["seed"]})' for r in mine if r['collision']})
        if hits:
            lines.append(f'{name}: COLLIDED in {len(hits)} of {len(mine)} runs: '
                         + ', '.join(hits) + '.')
        else:
            lines.append(f'{name}: zero collisions in {len(mine)} runs over '
                         f'{len({r["scenario"] for r in mine})} scenarios.')
        grazes = [r for r in mine if not r['collision'] and r['min_clearance_m'] is not None
                  and r['min_clearance_m'] < GRAZE]
        if grazes:
            lines.append(f'{name}: came within {100 * GRAZE:.0f} cm (no collision) in: '
                         + ', '.join(f'{r["scenario"]} (seed {r["seed"]}, '
                                     f'{r["min_clearance_m"]:.4f} m)' for r in grazes) + '.')
        escapes = [r for r in mine if (r['fallback_steps'] or {}).get('escape')]
        if escapes:
            lines.append(f'{name}: reference point inside an inflated obstacle (escape '
                         'fallback) in: ' + ', '.join(
                             f'{r["scenario"]} (seed {r["seed"]}, '
                             f'{r["fallback_steps"]["escape"]} steps)' for r in escapes) + '.')
    if 'c3bf' in filters:
        for scenario in [s for s in PAPER_CLAIM if s in scenarios]:
            mine = [r for r in records if r['filter'] == 'c3bf' and r['scenario'] == scenario]
            failed = [r for r in mine if not r['success']]
            rescued = [r for r in failed if r['goal_reached'] and r['fallback_at_start']]
            if failed:
                verdict = (f'fails in {len(failed)}/{len(mine)} runs ('
                           + ', '.join(sorted({_why(r) for r in failed})) + ')')
                if rescued:
                    verdict += (f'; in {len(rescued)} of them it starts inside its virtual '
                                'obstacle (no cone, the failure the paper describes) and only '
                                "this package's escape fallback, which the paper's C3BF does "
                                'not have, then takes it out and on to the goal')
            else:
                verdict = (f"succeeds in all {len(mine)} runs: the paper's claim is NOT "
                           'reproduced here')
            lines.append(f'c3bf on {scenario}: {verdict}.')
    for name in [f for f in filters if f != 'none']:
        stuck = [r for r in records if r['filter'] == name and not r['goal_reached']
                 and not r['collision']]
        if stuck:
            lines.append(f'{name} did not reach the goal in: ' + ', '.join(
                f'{r["scenario"]} (seed {r["seed"]}, {_why(r)})' for r in stuck) + '.')
        lines += _deadlock_finding(name, [r for r in records if r['filter'] == name])
        slow = [row for row in rows if row['filter'] == name
                and (row['time_to_goal_ratio'] or 0.0) > 1.25]
        if slow:
            lines.append(f'{name} is conservative (time to goal > 1.25 x nominal) in: '
                         + ', '.join(f'{row["scenario"]} ({row["time_to_goal_ratio"]:.2f}x)'
                                     for row in slow) + '.')
    if 'none' in filters:
        hits = sorted({r['scenario'] for r in records if r['filter'] == 'none' and r['collision']})
        lines.append(f'no filter: collides in {len(hits)} of {len(scenarios)} scenarios'
                     + (f' ({", ".join(hits)})' if hits else '') + ': the scenarios are not '
                     'trivially safe.')
    return lines


def _deadlock_finding(name, records):
    """One line: how the deadlock report compares with the runs labelled deadlock."""
    labelled = [r for r in records if r['deadlock']]
    detected = [r for r in records if r['deadlock_detections']]
    if not (labelled or detected):
        return []
    flagged = sum(r['deadlocked_at_end'] for r in labelled)
    freed = [r for r in detected if r['goal_reached']]
    missed = [r for r in labelled if not r['deadlocked_at_end']]
    line = (f'{name}: the deadlock report flagged {flagged} of the {len(labelled)} runs '
            f'labelled deadlock at their end; {len(detected)} runs had a report')
    if freed:
        line += f', {len(freed)} of them then reached the goal (the robot got free)'
    if missed:
        line += ('; not flagged: ' + ', '.join(f'{r["scenario"]} (seed {r["seed"]})'
                                               for r in missed))
    return [line + '.']


def _why(record):
    """Return a short reason for a run's outcome (with the filter's dominant fallback)."""
    outcome = record['outcome']
    steps = record.get('fallback_steps') or {}
    escape = steps.get('escape', 0)
    if escape:
        outcome += f', escape in {100 * escape / record["steps"]:.0f} % of steps'
    return outcome


def obstacle_sources(records):
    """Return where the records' obstacles came from, with the lidar settings of scans."""
    texts = {}
    for record in records:
        lidar = record.get('lidar')
        settings = '' if lidar is None else ' (lidar ' + ', '.join(
            f'{name} {value}' for name, value in lidar.items() if name != 'frame_id') + ')'
        texts.setdefault(record['obstacle_source'] + settings, None)
    return '; '.join(texts)


def actuation_line(records):
    """Return how the records' plants took commands and reported odometry (``actuation``)."""
    return '; '.join(dict.fromkeys(describe_actuation(record.get('actuation'))
                                   for record in records))


def write_outputs(out, records, runs, command, plots_too=True):
    """Write results.json, results.md and (unless ``plots_too`` is False) the PNGs."""
    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    (out / 'results.json').write_text(json.dumps(records, indent=1) + '\n')
    rows = aggregate(records)
    load = ', '.join(f'{v:.2f}' for v in os.getloadavg())
    units = ', '.join(sorted({r['intervention_units'] for r in records}))
    text = ['# Evaluation: PolyC2BF vs C3BF (lockstep, in-process)', '',
            f'Command: `{command}`  ',
            f'Date: {datetime.now().isoformat(timespec="seconds")}, load average after the run: '
            f'{load}.  ',
            f'Obstacles: {obstacle_sources(records)}.  ',
            f'Actuation: {actuation_line(records)}.  ',
            f'{len(records)} runs; per run JSON in `results.json`.  Definitions: '
            '`sim_bridge/evaluation/scenario_suite.py` docstring.  Counts are runs (seeds) '
            'with that property; '
            '"no cone at t=0": the filter fell back (escape: the robot starts inside the '
            '(virtual) obstacle, where the barrier is undefined) on the first step; '
            f'min clearance is the minimum over seeds ("> {CLEARANCE_RANGE:g}": nothing came '
            f'within {CLEARANCE_RANGE:g} m); '
            f'intervention units: {units}.',
            '', markdown_table(rows), '', '## Findings', '']
    text += [f'- {line}' for line in findings(records, rows)]
    (out / 'results.md').write_text('\n'.join(text) + '\n')
    if plots_too and runs:
        _plots(out, runs, rows)
    return rows


def _plots(out, runs, rows):
    """Write trajectories.png (first seed per scenario) and metrics.png."""
    panels, seen = {}, {}
    radius = {}
    for run in runs:
        first = seen.setdefault(run.scenario.name, run.scenario.seed)
        if run.scenario.seed != first:
            continue
        scenario, by_filter, collisions = panels.setdefault(
            run.scenario.name, (run.scenario, {}, []))
        by_filter[run.barrier] = [t.positions() for t in run.robots.values()]
        if run.robot_radius is not None:
            radius[run.scenario.name] = run.robot_radius
        for name, trace in run.robots.items():
            when = run.metrics[name]['collision_time_s']
            if when is not None:
                collisions.append(trace.positions()[min(len(trace.times),
                                                        round(when / run.period))])
    plots.grid_figure(out / 'trajectories.png', list(panels.values()),
                      lambda s: radius.get(s.name, 0.0),
                      'Paths per scenario (first seed); red dotted: C3BF virtual obstacles')
    scenarios = list(dict.fromkeys(r['scenario'] for r in rows))
    filters = list(dict.fromkeys(r['filter'] for r in rows))
    plots.metrics_figure(out / 'metrics.png', rows, filters, scenarios)
