"""Re-record the regression bags of ``test/replay`` (see ``test/data/README.md``).

Usage, from the repository root::

    .venv/bin/python test/data/record_regression_bags.py            # every bag
    .venv/bin/python test/data/record_regression_bags.py popup_obstacle

Each bag is one lockstep closed-loop run of a shipped scenario over localhost
DDS, started by ``sim_bridge.launcher``: ``sim_bridge``, ``nominal_controller``
and ``safety_filter`` as separate processes, the filter with its shipped
parameter file plus the launcher's lockstep overrides (``trigger: command``,
``match_stamps: true``, ...).  The bag lands in ``test/data/<name>/`` as
``<name>_0.mcap`` + ``metadata.yaml`` (zstd chunks), beside ``recording.json``:
scenario, robot, goal, the filter's parameter file and overrides (the tests
start the filter and configure the offline check from it), and the bridge's
metrics.  A bag over ``MAX_BYTES`` is an error.  The domain is
``ROS_DOMAIN_ID`` if set (loopback only), else the launcher picks one.
"""
import argparse
import json
import shutil
import subprocess
import sys
import tempfile
from pathlib import Path

REPO = Path(__file__).resolve().parents[2]
sys.path.insert(0, str(REPO))

from sim_bridge.launcher import closed_loop_plan, run_closed_loop  # noqa: E402
from sim_bridge.scenario import load_scenario  # noqa: E402

DATA = Path(__file__).resolve().parent
MAX_BYTES = 1_000_000
BARRIER = 'polyc2bf_inflated'
# The deadlock report runs on the node's steady clock, which a lockstep recording does not
# reproduce offline to the step: the bags score the filter's commands, so nothing resolves.
FILTER_PARAMETERS = {'deadlock_resolution': 'none'}
# name: (scenario, sim duration [s], what the bag is for, more filter parameters)
RECORDINGS = {
    'wall_approach': ('long_wall', 14.0,
                      'head-on approach of a 20 m wall: the filter slows and turns the robot', {}),
    # The paper's QP cost, which brakes straight: quadruped.yaml's steering weight turns
    # round the box instead (test/eval/test_in_process_loop.py covers that).
    'popup_obstacle': ('popup_obstacle', 6.0,
                       'a box appears 1.75 m ahead at t = 3 s: the filter must stop in time',
                       {'model_params.steering_weight': 1.0}),
    'clear_path': ('clear_path', 8.0,
                   'boxes well off the path: the filter must not intervene', {}),
    'quadrotor_pillars': ('quadrotor_pillars', 3.0,
                          'thrust-level Crazyflie among pillars: the wrench path, offline', {}),
}


def record(name):
    """Record bag ``name`` into ``test/data/<name>/``; return its recording.json data."""
    scenario_name, duration, purpose, extra = RECORDINGS[name]
    parameters = {**FILTER_PARAMETERS, **extra}
    scenario = load_scenario(scenario_name)
    bag_dir = DATA / name
    if bag_dir.exists():
        shutil.rmtree(bag_dir)
    with tempfile.TemporaryDirectory(prefix=f'record_{name}_') as run_dir:
        result = run_closed_loop(scenario, run_dir, barrier=BARRIER, duration=duration,
                                 bridge_parameters={'bag_path': str(bag_dir)},
                                 filter_parameters=parameters)
        if not result.ok:
            raise RuntimeError(f'{name}: the run failed: {result.message}')
        metrics = result.metrics()
    plan = closed_loop_plan(scenario, BARRIER, {'duration': duration}, parameters)
    (robot,) = scenario.robots
    (spec,) = [p for p in plan if p.executable == 'safety_filter']
    size = sum(f.stat().st_size for f in bag_dir.glob('*.mcap'))
    if size > MAX_BYTES:
        raise RuntimeError(f'{name}: {size} bytes, over the {MAX_BYTES} byte limit')
    info = {
        'purpose': purpose,
        'scenario': scenario_name, 'duration_s': duration, 'robot': robot.name,
        'robot_type': robot.type, 'goal': [float(g) for g in robot.goal],
        'filter_params_file': str(spec.params_file.relative_to(REPO)),
        'filter_parameters': spec.parameters,
        'commit': _git('rev-parse', '--short', 'HEAD'),
        'tree_modified': bool(_git('status', '--porcelain', '--untracked-files=no')),
        'mcap_bytes': size,
        'metrics': metrics['robots'][robot.name],
    }
    (bag_dir / 'recording.json').write_text(json.dumps(info, indent=1) + '\n')
    return info


def _git(*args):
    done = subprocess.run(['git', *args], cwd=REPO, capture_output=True, text=True)
    return done.stdout.strip()


def main(argv=None):
    """Record the named bags (default: all); exit status 1 if one fails."""
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument('names', nargs='*', help=f'bags to record: {", ".join(RECORDINGS)} '
                        '(default: all)')
    names = parser.parse_args(argv).names or list(RECORDINGS)
    unknown = sorted(set(names) - set(RECORDINGS))
    if unknown:
        parser.error(f'unknown bag {", ".join(unknown)}; known: {", ".join(RECORDINGS)}')
    failed = False
    for name in names:
        print(f'recording {name} ...', flush=True)
        try:
            info = record(name)
        except RuntimeError as exc:
            print(f'  FAILED: {exc}', flush=True)
            failed = True
            continue
        print(f'  {info["mcap_bytes"]} bytes; collision {info["metrics"]["collision"]}, '
              f'min clearance {info["metrics"]["min_clearance_m"]} m', flush=True)
    return 1 if failed else 0


if __name__ == '__main__':
    sys.exit(main())
