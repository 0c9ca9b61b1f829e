"""One record per run, shared by every suite: what the robots and the filter did.

``summarise`` makes a scenario-suite record (its keys: ``scenario_suite``);
``filter_statistics`` and ``lidar_record`` are the parts the BARN and dynamic suites reuse;
``group_records`` / ``aggregate`` fold records into table rows.
"""
import dataclasses
import math

import numpy as np

from sim_bridge.metrics import GOAL_TOLERANCE
from sim_bridge.robots import robot_type

STALL_TIME = 3.0      # s


STALL_SPEED = 0.05    # m/s


FALLBACKS = ('slack', 'brake', 'escape', 'backup', 'evade')


KEYS = ('scenario', 'filter', 'seed', 'obstacle_source', 'success', 'collision', 'deadlock',
        'min_clearance_m', 'time_to_goal_ratio', 'mean_intervention', 'fallback_rate',
        'latency_p50_us', 'latency_p99_us')


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


STEP_KEYS = ('latency_p50_us', 'latency_p99_us', 'fallback_steps', 'steps',
             'deadlock_detections', 'deadlocked_at_end', 'negative_h_rate', 'deepest_h')
"""The keys of ``filter_statistics`` the BARN and dynamic suites' records carry as they are."""


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
