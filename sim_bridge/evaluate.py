"""``evaluate``: every filter x scenario x seed in lockstep, as a table, JSON and plots.

Usage::

    evaluate [--scenarios long_wall ...] [--filters c3bf none ...] [--seeds 0 1 2]
             [--random-seeds 3] [--duration S] [--out runs/eval] [--no-plots]
             [--obstacle-source markers|scan] [--lidar FIELD=VALUE ...]
    evaluate --suite barn [--worlds FILE] [--nominal path|goal ...] [--filters ...]
             [--jobs N] [--limit K] [--out runs/barn] [--no-plots] [--obstacle-source ...]
    evaluate --suite dynamic [--worlds 0-19 45 ...] [--difficulty easy medium hard]
             [--nominal goal|path ...] [--filters ...] [--jobs N] [--out runs/dynamic]
             [--no-plots] [--obstacle-source ...]
    every suite also: [--latency S] [--actuator-tau S] [--odom-noise M] [-p NAME:=VALUE ...]

``--filters`` takes ``polyc2bf_paper``, ``polyc2bf_inflated``, ``c3bf``, ``none``
and ``default`` (the barrier the robot type's shipped parameter file runs).  The
BARN suite (``sim_bridge.barn``, ``sim_bridge.barn_suite``) runs the worlds of
``--worlds`` (default: the shipped ``bench/data/barn/barn_worlds.json``; ``--limit``:
the first K) with each nominal (default ``path``) and filter (default
``default``) over ``--jobs`` processes (default: the CPU count).  The dynamic suite
(``sim_bridge.dynamic_worlds``, ``sim_bridge.dynamic_suite``) runs the 60 generated
worlds of moving cylinders (``--worlds``: ids and ranges; ``--difficulty``: some of
easy, medium, hard) with each nominal (default ``goal``) and filter (default
``default``), also over ``--jobs`` processes.

``--obstacle-source`` (every suite): ``markers`` (default), the ground-truth
polygons the bridge publishes, or ``scan``: each filtered robot carries the
simulated 2-D lidar of ``sim_bridge.lidar`` (``LidarSettings`` defaults: 360
beams over 360 deg, 10 m, 10 Hz, no noise, the scan plane through the base
origin; ``--lidar FIELD=VALUE`` changes one) and its filter gets only what the
node makes of the scans (``closed_loop``).  The dynamic suite's markers go through
the node's obstacle pipeline, so its filter uses estimated velocities, not the true
ones.  Every record carries ``obstacle_source`` (and ``lidar``, the settings, in scan
mode); the tables have an ``obstacles`` column.

``--latency``, ``--actuator-tau``, ``--odom-noise`` (every suite, default 0: the exact
lockstep arena): the plants act on each command that long after it is sent, follow it
to first order, and the filters get odometry with that much position noise
(``sim_bridge.actuation``).  Every record carries ``actuation`` and every table header
says it.  What follows describes the scenario suite.

Each run is the in-process lockstep loop of ``sim_bridge.closed_loop`` (the
PyBullet world, the ``nominal_controller`` law and the node's ``CommandFilter``),
deterministic and much faster than the DDS loop.  Scenarios with random obstacles
run once per seed (``--seeds``, default the scenario's seed and the next
``--random-seeds`` - 1); the others once.  Each scenario also runs once without
obstacles and without a filter, for its own duration (not ``--duration``): the
nominal time to goal.

Per run (one record in ``results.json``; the keys of doc/design.md, result records, first):

- ``collision``: a robot's PyBullet closest-point distance fell below -1 mm
  (``sim_bridge.metrics``); ``min_clearance_m``: the smallest such distance
  over robots and time (null: nothing came within 0.5 m);
- ``success``: every robot reached its goal (within 0.25 m) without collision,
  and the filter's barrier was defined at the start (``fallback_at_start``
  false): a CBF guarantees safety only from inside its safe set, so a run that
  starts where the barrier does not exist is a failure of the method even if
  this package's escape fallback then brings the robot to the goal
  (``goal_reached`` tells);
- ``deadlock``: no collision, some robot away from its goal at the end and
  stalled: speed below ``STALL_SPEED`` for the last ``STALL_TIME`` s.
  ``outcome`` names the case: collision, ``no_cone_at_start``, success,
  deadlock or ``timeout`` (not at the goal at the end, still moving), the
  first that applies;
- ``time_to_goal_ratio``: mean over robots of time to goal / the same robot's
  time in the obstacle-free nominal run (null unless every robot arrived);
- ``mean_intervention``: mean over periods and robots of ``||u - clip(u_nom)||``
  in the model's input units (unicycle ``[a, alpha]`` in m/s^2 and rad/s^2;
  quadrotor rotor thrusts in N), ``u_nom = (v_cmd - v) / T`` clipped to the
  input box: the part of the change that obstacles, not the input bounds, made
  (``mean_intervention_unclipped`` keeps the raw ``||u - u_nom||``);
- ``fallback_rate``: share of filter steps with status slack, brake or escape;
  ``fallback_at_start``: the first step already fell back (a robot starts inside
  its (virtual) obstacle: no cone, the C3BF failure the paper describes);
- ``latency_p50_us`` / ``latency_p99_us``: wall time of ``CommandFilter.filter``
  per step, in this process (not the node's DDS round trip);
- ``deadlock_detections``: onsets of the node's deadlock report (``core.deadlock``: held in
  place by the filter against the nominal for ``deadlock_time``) summed over robots;
  ``deadlocked_at_end``: some robot was reported deadlocked at the last step.  The
  findings compare them with the ``deadlock`` label (which looks at the speed only).

Filter-dependent values are null for ``none``.  Output in ``--out``:
``results.json``, ``results.md`` (table per scenario x filter aggregated over
seeds, and findings), ``trajectories.png`` (top view per scenario, first seed,
all filters overlaid) and ``metrics.png``.
"""
import argparse
import dataclasses
import json
import math
import os
import sys
import time
from datetime import datetime
from pathlib import Path

import numpy as np
import yaml

from polyc2bf_ros.core.decision import RESOLUTIONS
from polyc2bf_ros.filter_parameters import ParameterError
from sim_bridge import plots
from sim_bridge.actuation import Actuation, describe as describe_actuation
from sim_bridge.closed_loop import default_barrier, NOMINALS, obstacle_free, run_in_process
from sim_bridge.dynamic_worlds import DIFFICULTIES
from sim_bridge.launcher import FILTER_CHOICES, OBSTACLE_SOURCES
from sim_bridge.lidar import lidar_settings, PARAMETER_FIELDS as LIDAR_FIELDS
from sim_bridge.metrics import GOAL_TOLERANCE
from sim_bridge.robots import robot_type
from sim_bridge.scenario import load_scenario, scenario_names
from sim_bridge.world import CLEARANCE_RANGE

STALL_TIME = 3.0      # s
STALL_SPEED = 0.05    # m/s
FALLBACKS = ('slack', 'brake', 'escape', 'backup', 'evade')
GRAZE = 0.01          # m: clearances below this are reported as near-contacts
DEFAULT_RANDOM_SEEDS = 3
FILTER_NAMES = FILTER_CHOICES + ('default',)
SUITES = ('scenarios', 'barn', 'dynamic')
KEYS = ('scenario', 'filter', 'seed', 'obstacle_source', 'success', 'collision', 'deadlock',
        'min_clearance_m', 'time_to_goal_ratio', 'mean_intervention', 'fallback_rate',
        'latency_p50_us', 'latency_p99_us')
POLYC2BF = ('polyc2bf_paper', 'polyc2bf_inflated')
PAPER_CLAIM = ('long_wall', 'semi_infinite_wall')  # where the paper says C3BF fails


def _round(value, digits=4):
    return None if value is None or not math.isfinite(value) else round(float(value), digits)


def _robot_record(trace, metrics, reference_time, period):
    """Per-robot outcome of one run (see the module docstring)."""
    final_distance = float(np.linalg.norm(trace.positions()[-1] - trace.goal))
    window = max(1, round(STALL_TIME / period))
    stalled = bool(trace.speeds()[-window:].max() < STALL_SPEED)
    at_goal = final_distance <= GOAL_TOLERANCE
    deadlock = not metrics['collision'] and not at_goal and stalled
    ratio = None
    if metrics['goal_reached'] and reference_time:
        ratio = metrics['time_to_goal_s'] / reference_time
    return {'collision': metrics['collision'], 'collision_time_s': metrics['collision_time_s'],
            'goal_reached': metrics['goal_reached'], 'time_to_goal_s': metrics['time_to_goal_s'],
            'reference_time_to_goal_s': reference_time, 'time_to_goal_ratio': _round(ratio),
            'min_clearance_m': metrics['min_clearance_m'], 'final_distance_m':
            round(final_distance, 4), 'stalled': stalled, 'deadlock': deadlock,
            'path_length_m': metrics['path_length_m']}


def filter_statistics(run):
    """Return what the filter did in a run (module docstring); filter-only values None for none.

    Keys: mean_intervention, fallback_rate, latency_p50_us, latency_p99_us,
    mean_intervention_unclipped, intervention_units, fallback_steps, fallback_at_start,
    steps, deadlock_detections, deadlocked_at_end, negative_h_rate (share of filtered steps
    that start outside the safe set, some h < 0), deepest_h (the smallest h of the run).
    """
    filtered = run.barrier != 'none'
    statuses = [s for trace in run.robots.values() for s in trace.statuses]
    latency = np.concatenate([t.latency_s for t in run.robots.values()]) * 1e6
    clipped, raw = [], []
    for trace in run.robots.values():
        u_nom = np.clip(trace.u_nom, *trace.input_box)
        clipped.append(np.linalg.norm(trace.u - u_nom, axis=1))
        raw.append(np.linalg.norm(trace.u - trace.u_nom, axis=1))
    counts = {status: statuses.count(status) for status in FALLBACKS}
    min_h = np.concatenate([t.min_h for t in run.robots.values()])
    finite = min_h[np.isfinite(min_h)]
    return {
        'mean_intervention': _round(float(np.mean(np.concatenate(clipped)))) if filtered
        else None,
        'fallback_rate': _round(sum(counts.values()) / len(statuses), 5) if filtered else None,
        'latency_p50_us': _round(float(np.percentile(latency, 50)), 1) if filtered else None,
        'latency_p99_us': _round(float(np.percentile(latency, 99)), 1) if filtered else None,
        'mean_intervention_unclipped': _round(float(np.mean(np.concatenate(raw))))
        if filtered else None,
        'intervention_units': _units(run),
        'fallback_steps': counts if filtered else None,
        'fallback_at_start': any(t.statuses[0] in FALLBACKS for t in run.robots.values()
                                 if t.statuses),
        'steps': len(statuses),
        'deadlock_detections': sum(int(np.count_nonzero(np.diff(t.deadlocked.astype(int),
                                                                 prepend=0) == 1))
                                   for t in run.robots.values()),
        'deadlocked_at_end': any(bool(t.deadlocked[-1]) for t in run.robots.values()
                                 if len(t.deadlocked)),
        'negative_h_rate': _round(float(np.mean(finite < 0)), 5) if filtered and finite.size
        else None,
        'deepest_h': _round(float(finite.min())) if filtered and finite.size else None,
    }


def summarise(run, reference_times):
    """Return the result record of one ClosedLoopRun (doc/design.md result keys + extras)."""
    robots = {}
    for name, trace in run.robots.items():
        robots[name] = _robot_record(trace, run.metrics[name], reference_times.get(name),
                                     run.period)
    stats = filter_statistics(run)
    clearances = [r['min_clearance_m'] for r in robots.values()
                  if r['min_clearance_m'] is not None]
    ratios = [r['time_to_goal_ratio'] for r in robots.values()]
    collision = any(r['collision'] for r in robots.values())
    reached = all(r['goal_reached'] for r in robots.values())
    no_cone = stats['fallback_at_start']
    success = reached and not collision and not no_cone
    deadlock = any(r['deadlock'] for r in robots.values())
    outcome = ('collision' if collision else 'no_cone_at_start' if no_cone else 'success'
               if success else 'deadlock' if deadlock else 'timeout')
    record = {
        'scenario': run.scenario.name, 'filter': run.barrier, 'seed': run.scenario.seed,
        'obstacle_source': run.obstacle_source, 'success': success, 'collision': collision,
        'deadlock': deadlock,
        'min_clearance_m': min(clearances) if clearances else None,
        'time_to_goal_ratio': _round(float(np.mean(ratios))) if None not in ratios else None,
        'mean_intervention': stats['mean_intervention'],
        'fallback_rate': stats['fallback_rate'],
        'latency_p50_us': stats['latency_p50_us'],
        'latency_p99_us': stats['latency_p99_us'],
        'outcome': outcome,
        'mean_intervention_unclipped': stats['mean_intervention_unclipped'],
        'intervention_units': stats['intervention_units'],
        'fallback_steps': stats['fallback_steps'],
        'fallback_at_start': no_cone, 'goal_reached': reached,
        'deadlock_detections': stats['deadlock_detections'],
        'deadlocked_at_end': stats['deadlocked_at_end'],
        'negative_h_rate': stats['negative_h_rate'], 'deepest_h': stats['deepest_h'],
        'penetration_m': _round(max(0.0, -min(clearances))) if clearances else None,
        'steps': stats['steps'], 'duration_s': run.scenario.duration,
        'wall_time_s': round(run.wall_time_s, 2), 'robots': robots, 'lidar': lidar_record(run),
        'actuation': run.actuation.record(),
    }
    return record


def lidar_record(run):
    """Return the run's lidar settings as a dict (None unless its obstacles came from scans)."""
    return None if run.lidar is None else dataclasses.asdict(run.lidar)


def _units(run):
    return ', '.join(sorted({robot_type(run.scenario.robot(name).type).input_units
                             for name in run.robots}))


# -- progress ------------------------------------------------------------------------------

class Progress:
    """A progress bar with ETA on stderr (scenario suite: simulated robot-seconds; BARN: runs)."""

    def __init__(self, total, stream=None, width=30):
        """Expect ``total`` units of work; write to ``stream`` (stderr)."""
        self.total = max(total, 1e-9)
        self.done = 0.0
        self.stream = stream or sys.stderr
        self.width = width
        self.start = time.monotonic()
        self.tty = self.stream.isatty()
        self._last = 0.0

    def update(self, done, label, force=False):
        """Show ``done`` units finished, working on ``label``."""
        self.done = done
        now = time.monotonic()
        if not force and now - self._last < (0.2 if self.tty else 10.0):
            return
        self._last = now
        share = min(self.done / self.total, 1.0)
        elapsed = now - self.start
        eta = elapsed * (1.0 - share) / share if share > 0 else math.nan
        bar = '#' * int(share * self.width)
        text = (f'[{bar:<{self.width}}] {100 * share:5.1f} %  {elapsed:6.0f} s elapsed, '
                f'ETA {eta:5.0f} s  {label}')
        self.stream.write(('\r' + text[:160].ljust(160)) if self.tty else text + '\n')
        self.stream.flush()

    def close(self):
        """End the bar's line."""
        if self.tty:
            self.stream.write('\n')
            self.stream.flush()


# -- the suite ------------------------------------------------------------------------------

def resolve_filters(filters, robot_type):
    """Return ``filters`` with ``default`` replaced by ``robot_type``'s shipped barrier, unique."""
    return list(dict.fromkeys(default_barrier(robot_type) if name == 'default' else name
                              for name in filters))


def plan_runs(scenarios, filters, seeds=None, random_seeds=DEFAULT_RANDOM_SEEDS, duration=None):
    """Return ``[(Scenario, filter)]``: random scenarios once per seed, the others once.

    ``default`` is the shipped barrier of the scenario's first robot's type.
    """
    runs = []
    for name in scenarios:
        base = load_scenario(name)
        chosen_filters = resolve_filters(filters, base.robots[0].type)
        if duration is not None:
            base = dataclasses.replace(base, duration=float(duration))
        if base.random_obstacles is not None:
            chosen = seeds if seeds else [base.seed + i for i in range(random_seeds)]
            variants = [base.with_seed(s) for s in chosen]
        else:
            variants = [base]
        runs += [(variant, barrier) for variant in variants for barrier in chosen_filters]
    return runs


def run_suite(scenarios, filters, seeds=None, random_seeds=DEFAULT_RANDOM_SEEDS,
              duration=None, progress=True, parameters=None, obstacle_source='markers',
              lidar=None, actuation=None):
    """Run the obstacle-free references and every planned run; return (records, runs).

    ``parameters``: node parameters that override the parameter files'; ``obstacle_source``
    and ``lidar``: where the filters' obstacles come from (``run_in_process``).  The
    references have no obstacles and no filter, so no lidar; every run, the references'
    too, has the plants' ``actuation`` (``run_in_process``).
    """
    planned = plan_runs(scenarios, filters, seeds, random_seeds, duration)
    # References run for the scenario file's own duration, whatever ``duration`` says.
    references = {}
    for name in scenarios:
        scenario = load_scenario(name)
        references.setdefault(scenario.name, obstacle_free(scenario))
    work = [(s, 'none', True) for s in references.values()] + [(s, f, False) for s, f in planned]
    total = sum(s.duration * len(s.robots) for s, _, _ in work)
    bar = Progress(total) if progress else None
    done = 0.0
    reference_times, records, runs = {}, [], []
    for scenario, barrier, is_reference in work:
        label = (f'{scenario.name} (obstacle-free reference)' if is_reference
                 else f'{scenario.name} seed {scenario.seed} {barrier}')
        weight = len(scenario.robots)

        def report(sim_time, _duration, base=done, weight=weight, label=label):
            if bar is not None:
                bar.update(base + sim_time * weight, label)

        source = 'markers' if is_reference else obstacle_source
        run = run_in_process(scenario, barrier, progress=report, parameters=parameters,
                             obstacle_source=source, lidar=lidar, actuation=actuation)
        done += scenario.duration * weight
        if is_reference:
            reference_times[scenario.name] = {name: m['time_to_goal_s']
                                              for name, m in run.metrics.items()}
            continue
        records.append(summarise(run, reference_times[scenario.name]))
        runs.append(run)
        if bar is not None:
            bar.update(done, label, force=True)
    if bar is not None:
        bar.close()
    return records, runs


# -- tables and findings --------------------------------------------------------------------

def group_records(records, *keys):
    """Return ``{(record[k] for k in keys): [records]}``, groups in first-record order."""
    groups = {}
    for record in records:
        groups.setdefault(tuple(record[key] for key in keys), []).append(record)
    return groups


def aggregate(records):
    """Return one row per (scenario, filter), aggregated over seeds, in record order."""
    rows = []
    for (scenario, name, source), group in group_records(records, 'scenario', 'filter',
                                                          'obstacle_source').items():
        def values(key, group=group):
            return [r[key] for r in group if r[key] is not None]

        clearances = values('min_clearance_m')
        ratios = values('time_to_goal_ratio')
        rows.append({
            'scenario': scenario, 'filter': name, 'obstacle_source': source,
            'runs': len(group),
            'success': sum(r['success'] for r in group),
            'collision': sum(r['collision'] for r in group),
            'deadlock': sum(r['deadlock'] for r in group),
            'timeout': sum(not (r['goal_reached'] or r['deadlock'] or r['collision'])
                           for r in group),
            'fallback_at_start': sum(r['fallback_at_start'] for r in group),
            'success_rate': sum(r['success'] for r in group) / len(group),
            'min_clearance_m': min(clearances) if clearances else None,
            'time_to_goal_ratio': float(np.mean(ratios)) if ratios else None,
            'mean_intervention': _mean(values('mean_intervention')),
            'fallback_rate': _mean(values('fallback_rate')),
            'latency_p50_us': float(np.median(values('latency_p50_us')))
            if values('latency_p50_us') else None,
            'latency_p99_us': max(values('latency_p99_us'), default=None),
            'negative_h_rate': _mean(values('negative_h_rate')),
        })
    return rows


def _mean(values):
    return float(np.mean(values)) if values else None


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
            '`sim_bridge/evaluate.py` docstring.  Counts are runs (seeds) with that property; '
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


def _parser():
    """Return the command line parser of every suite."""
    parser = argparse.ArgumentParser(prog='evaluate', description=__doc__.split('\n')[0])
    parser.add_argument('--suite', choices=SUITES, default='scenarios',
                        help='scenarios (default): the shipped scenario files; barn: BARN worlds; '
                        'dynamic: the generated worlds of moving cylinders')
    parser.add_argument('--filters', nargs='+', default=None, choices=FILTER_NAMES,
                        metavar='FILTER', help=f'filters among {", ".join(FILTER_NAMES)} '
                        '(default: all but default for scenarios, default for barn and dynamic)')
    parser.add_argument('--out', default=None,
                        help='output directory (default runs/eval, runs/barn, runs/dynamic)')
    parser.add_argument('--no-plots', action='store_true', help='skip the PNG plots')
    parser.add_argument('--deadlock-resolution', choices=RESOLUTIONS, default=None,
                        help="the filter's deadlock_resolution (default: the parameter "
                        "file's, 'none' as shipped)")
    parser.add_argument('--obstacle-source', choices=OBSTACLE_SOURCES, default='markers',
                        help="the filters' obstacles: markers (ground truth, default) or scan "
                        '(a simulated lidar on each robot, converted as the node does)')
    parser.add_argument('--lidar', action='append', default=[], metavar='FIELD=VALUE',
                        help='with --obstacle-source scan: a lidar setting (value read as '
                        f'YAML), FIELD one of {", ".join(LIDAR_FIELDS)}; repeatable')
    parser.add_argument('--latency', type=float, default=0.0, metavar='S',
                        help='the plants act on each command this long after it is sent '
                        '(default 0: at once; sim_bridge/actuation.py)')
    parser.add_argument('--actuator-tau', type=float, default=0.0, metavar='S',
                        help="time constant of the plants' first-order velocity (rotor) "
                        'response (default 0: at once)')
    parser.add_argument('--odom-noise', type=float, default=0.0, metavar='M',
                        help="standard deviation of the noise on the filters' odometry "
                        'position, per axis (default 0: exact)')
    parser.add_argument('-p', '--param', action='append', default=[], metavar='NAME:=VALUE',
                        help='set a node parameter of every filtered robot, as ros2 run -p '
                        '(value read as YAML), e.g. -p filter.horizon:=2.0; repeatable')
    scenarios = parser.add_argument_group('scenario suite')
    scenarios.add_argument('--scenarios', nargs='+', default=None, metavar='NAME',
                           help=f'scenarios (default: all shipped: {", ".join(scenario_names())})')
    scenarios.add_argument('--seeds', nargs='+', type=int, default=None,
                           help='seeds of the scenarios with random obstacles')
    scenarios.add_argument('--random-seeds', type=int, default=None,
                           help="without --seeds: this many seeds from the scenario's own "
                           f'(default {DEFAULT_RANDOM_SEEDS})')
    scenarios.add_argument('--duration', type=float, default=None,
                           help="sim seconds per run (default: each scenario's)")
    barn = parser.add_argument_group('barn and dynamic suites')
    barn.add_argument('--worlds', nargs='+', default=None, metavar='FILE|ID',
                      help='barn: the world file (default: the shipped bench/data/barn copy); '
                      'dynamic: world ids and ranges, e.g. 0-19 45 (default: all 60)')
    barn.add_argument('--nominal', nargs='+', choices=NOMINALS, default=None,
                      help='nominal controller(s): path and/or goal (default: path for barn, '
                      'goal for dynamic)')
    barn.add_argument('--jobs', type=int, default=None,
                      help='processes (default: the CPU count)')
    barn.add_argument('--limit', type=int, default=None, metavar='K',
                      help='barn: only the first K worlds of the file')
    barn.add_argument('--difficulty', nargs='+', choices=list(DIFFICULTIES), default=None,
                      help='dynamic: only worlds of these difficulties (default: all)')
    return parser


def override_parameters(args):
    """Return the node parameters the command line sets (``--param``, ``--deadlock-resolution``).

    Raise ValueError on a ``--param`` without ``:=``.
    """
    parameters = {}
    for item in args.param:
        name, separator, value = item.partition(':=')
        if not separator or not name:
            raise ValueError(f'--param wants NAME:=VALUE, got {item!r}')
        parameters[name] = yaml.safe_load(value)
    if args.deadlock_resolution is not None:
        parameters['deadlock_resolution'] = args.deadlock_resolution
    return parameters


def actuation_from_args(parser, args):
    """Return the Actuation of ``--latency``, ``--actuator-tau``, ``--odom-noise``; 2 if bad."""
    try:
        return Actuation(args.latency, args.actuator_tau, args.odom_noise).validate()
    except ValueError as exc:
        parser.error('--' + str(exc).replace('_', '-', 1))  # names the option


def lidar_from_args(parser, args):
    """Return the LidarSettings of ``--lidar`` in scan mode (None with markers); exit 2 if bad."""
    if args.obstacle_source != 'scan':
        if args.lidar:
            parser.error('--lidar needs --obstacle-source scan')
        return None
    try:
        return lidar_settings(args.lidar)
    except ValueError as exc:
        parser.error(str(exc))


SUITE_OPTIONS = {'scenarios': ('scenarios', 'seeds', 'random_seeds', 'duration'),
                 'barn': ('worlds', 'nominal', 'jobs', 'limit'),
                 'dynamic': ('worlds', 'nominal', 'jobs', 'difficulty')}


def _misplaced_options(suite, args):
    """Return {owning suites: [given options]} for options given that ``suite`` does not take."""
    owners = {}
    for name, options in SUITE_OPTIONS.items():
        for option in options:
            owners.setdefault(option, []).append(name)
    misplaced = {}
    for option, suites in owners.items():
        if suite not in suites and getattr(args, option) is not None:
            misplaced.setdefault(' or '.join(suites), []).append(
                f'--{option.replace("_", "-")}')
    return misplaced


def main(argv=None):
    """Run the evaluation suite and write its outputs; exit 0, 2 on bad arguments, 130 on ^C."""
    parser = _parser()
    args = parser.parse_args(argv)
    for suites, given in _misplaced_options(args.suite, args).items():
        parser.error(f'{", ".join(given)} belong(s) to --suite {suites}')
    command = ('evaluate ' + ' '.join(sys.argv[1:] if argv is None else argv)).strip()
    if args.suite == 'barn':
        if args.worlds is not None:
            if len(args.worlds) != 1:
                parser.error('--suite barn takes one --worlds FILE')
            args.worlds = args.worlds[0]
        # Imported here: the BARN suite builds on this module's record helpers.
        from sim_bridge.barn_suite import main_barn
        return main_barn(parser, args, command)
    if args.suite == 'dynamic':
        # Imported here, as for BARN: the dynamic suite builds on this module's helpers.
        from sim_bridge.dynamic_suite import main_dynamic
        return main_dynamic(parser, args, command)
    scenarios = args.scenarios or scenario_names()
    unknown = [s for s in scenarios if s not in scenario_names() and not Path(s).is_file()]
    if unknown:
        parser.error(f'unknown scenario(s) {", ".join(unknown)}; shipped: '
                     f'{", ".join(scenario_names())}')
    if args.duration is not None and args.duration <= 0:
        parser.error('--duration must be > 0')
    random_seeds = DEFAULT_RANDOM_SEEDS if args.random_seeds is None else args.random_seeds
    if random_seeds < 1:
        parser.error('--random-seeds must be >= 1')
    out = args.out or 'runs/eval'
    try:
        parameters = override_parameters(args)
    except ValueError as exc:
        parser.error(str(exc))
    lidar = lidar_from_args(parser, args)
    actuation = actuation_from_args(parser, args)
    try:
        records, runs = run_suite(scenarios, args.filters or list(FILTER_CHOICES), args.seeds,
                                  random_seeds, args.duration, parameters=parameters,
                                  obstacle_source=args.obstacle_source, lidar=lidar,
                                  actuation=actuation)
    except KeyboardInterrupt:
        print('\nevaluate: interrupted; nothing written', file=sys.stderr)
        return 130
    except ParameterError as exc:  # a -p value that some robot's filter refuses
        parser.error(str(exc))
    rows = write_outputs(out, records, runs, command, not args.no_plots)
    print(markdown_table(rows))
    print()
    for line in findings(records, rows):
        print(f'- {line}')
    print(f'\nwrote {Path(out) / "results.json"}, results.md'
          + ('' if args.no_plots else ', trajectories.png, metrics.png'))
    return 0


if __name__ == '__main__':
    sys.exit(main())
