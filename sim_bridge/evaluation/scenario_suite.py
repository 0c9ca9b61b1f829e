"""The scenario suite: every filter x scenario x seed in lockstep.

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
- ``deadlock_detections``: onsets of the node's deadlock report (``core.liveness.deadlock``: held
  in place by the filter against the nominal for ``deadlock_time``) summed over robots;
  ``deadlocked_at_end``: some robot was reported deadlocked at the last step.  The
  findings compare them with the ``deadlock`` label (which looks at the speed only).

Filter-dependent values are null for ``none``.  Output in ``--out``:
``results.json``, ``results.md`` (table per scenario x filter aggregated over
seeds, and findings), ``trajectories.png`` (top view per scenario, first seed,
all filters overlaid) and ``metrics.png``.
"""
import dataclasses

from sim_bridge.closed_loop import obstacle_free, run_in_process
from sim_bridge.evaluation.arguments import resolve_filters
from sim_bridge.evaluation.progress import Progress
from sim_bridge.evaluation.records import summarise
from sim_bridge.scenario import load_scenario

DEFAULT_RANDOM_SEEDS = 3



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
