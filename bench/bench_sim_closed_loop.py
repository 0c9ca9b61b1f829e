"""Benchmark the closed loop in lockstep: real-time factor and bridge memory.

Usage: python bench/bench_sim_closed_loop.py [--cases ...] [--out bench/results/sim.json]

Per case, as separate processes over real DDS (loopback, a private
ROS_DOMAIN_ID): ``sim_bridge`` (lockstep, recording its bag) and per robot a
``nominal_controller`` and a ``safety_filter`` (``trigger: command``).
real_time_factor = simulated time / wall time of the bridge's loop after every
robot answered the first period (from its metrics JSON); rss_mb = the bridge's
peak resident set (VmHWM).  Records are merged into ``--out``: records of the
same case with ``closed_loop: true`` are replaced, the sim-only ones of
bench/bench_sim.py kept.
"""
import argparse
import json
import os
import random
import signal
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import yaml

from sim_bridge.scenario import load_scenario

REPO = Path(__file__).resolve().parents[1]
CONTROL_RATE = 120.0  # the bridge's effective rate for 240 Hz physics / 100 Hz control

CASES = {
    # One A1 crossing 50 seeded random polygons (bench/bench_sim.py's case, as a file).
    'quadruped_50_obstacles': ({
        'name': 'quadruped_50_obstacles', 'duration': 10.0, 'seed': 7,
        'robots': [{'name': 'a1', 'type': 'quadruped', 'start': [0, 0, 0], 'goal': [20, 0]}],
        'random_obstacles': {'count': 50, 'region': [[2, -8], [18, 8]], 'size': [0.4, 1.0],
                             'height': [0.5, 1.5], 'clearance': 1.0, 'spacing': 0.9}}, 1),
    'crazyflie_pillars': (str(REPO / 'config' / 'scenarios' / 'quadrotor_pillars.yaml'), 1),
    # Eight A1s abreast in lanes 1.5 m apart, each seeing the other seven.
    'quadrupeds_8': ({
        'name': 'quadrupeds_8', 'duration': 5.0,
        'robots': [{'name': f'a1_{i}', 'type': 'quadruped', 'start': [0.0, 1.5 * i, 0.0],
                    'goal': [20.0, 1.5 * i]} for i in range(8)]}, 8),
}


def _ros(module, *args):
    return [sys.executable, '-m', module, '--ros-args', *args]


def robot_commands(robot):
    """Return the nominal controller and filter command lines of one scenario robot."""
    ns = ['-r', f'__ns:=/{robot["name"]}']
    goal = '[' + ','.join(str(float(g)) for g in robot['goal']) + ']'
    nominal = _ros('sim_bridge.nominal_controller_node', *ns, '-p',
                   f'robot_type:={robot["type"]}', '-p', f'goal:={goal}')
    if robot['type'] == 'quadruped':
        params = ['--params-file', str(REPO / 'config' / 'quadruped.yaml'), '-p',
                  'trigger:=command', '-p', 'stamped:=true']
    else:
        params = ['--params-file', str(REPO / 'config' / 'crazyflie_thrust.yaml')]
    filt = _ros('polyc2bf_ros.safety_filter_node', *ns, *params, '-p',
                f'rate:={CONTROL_RATE}', '-p', 'obstacles_timeout:=0.0')
    return [nominal, filt]


def peak_rss_mb(pid):
    """Return VmHWM of ``pid`` [MB], or None once it has exited."""
    try:
        for line in Path(f'/proc/{pid}/status').read_text().splitlines():
            if line.startswith('VmHWM:'):
                return int(line.split()[1]) / 1024.0
    except OSError:
        return None
    return None


def run_case(case, duration, workdir):
    """Run one case; return its record."""
    spec, robots = CASES[case]
    if isinstance(spec, dict):
        path = workdir / f'{case}.yaml'
        path.write_text(yaml.safe_dump(spec))
        scenario, robot_list = str(path), spec['robots']
    else:
        loaded = load_scenario(spec)
        scenario = spec
        robot_list = [{'name': r.name, 'type': r.type, 'goal': r.goal.tolist()}
                      for r in loaded.robots]
    metrics = workdir / f'{case}.json'
    env = {**os.environ, 'PYTHONPATH': str(REPO), 'ROS_LOG_DIR': str(workdir / 'log')}
    bridge = _ros('sim_bridge.bridge_node', '-p', f'scenario:={scenario}', '-p',
                  f'duration:={duration}', '-p', 'record:=true', '-p',
                  f'bag_path:={workdir / case}', '-p', f'metrics_path:={metrics}', '-p',
                  'startup_timeout:=120.0')
    log = open(workdir / f'{case}.log', 'w')
    children = [subprocess.Popen(cmd, env=env, stdout=log, stderr=subprocess.STDOUT)
                for robot in robot_list for cmd in robot_commands(robot)]
    proc = subprocess.Popen(bridge, env=env, stdout=log, stderr=subprocess.STDOUT)
    rss = 0.0
    try:
        while proc.poll() is None:
            rss = max(rss, peak_rss_mb(proc.pid) or 0.0)
            time.sleep(0.2)
    finally:
        for child in children + [proc]:
            if child.poll() is None:
                child.send_signal(signal.SIGINT)
        for child in children + [proc]:
            try:
                child.wait(timeout=10)
            except subprocess.TimeoutExpired:
                child.kill()
    result = json.loads(metrics.read_text())
    return {'bench': 'sim', 'case': case, 'robots': robots, 'closed_loop': True,
            'real_time_factor': result['real_time_factor'], 'rss_mb': round(rss, 1),
            'sim_seconds': result['sim_time_s'], 'wall_seconds': result['wall_time_s'],
            'control_rate': result['control_rate'], 'completed': result['completed'],
            'lockstep_timeouts': sum(result['lockstep_timeouts'].values()),
            'collisions': sum(r['collision'] for r in result['robots'].values()),
            'load_average_1m': round(os.getloadavg()[0], 2), 'cpus': os.cpu_count()}


def merge(out, records):
    """Replace this benchmark's records of the same cases in ``out``, keep all others."""
    existing = json.loads(out.read_text()) if out.exists() else []
    cases = {r['case'] for r in records}
    kept = [r for r in existing if not (r.get('closed_loop') and r.get('case') in cases)]
    out.parent.mkdir(parents=True, exist_ok=True)
    out.write_text(json.dumps(kept + records, indent=1) + '\n')


def main(argv=None):
    """Run the cases, print and merge their records into the results file."""
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument('--cases', nargs='+', choices=list(CASES), default=list(CASES))
    parser.add_argument('--duration', type=float, default=None,
                        help='sim seconds per case (default: 10 for one robot, 5 for eight)')
    parser.add_argument('--out', default=str(REPO / 'bench' / 'results' / 'sim.json'))
    args = parser.parse_args(argv)
    os.environ.setdefault('ROS_DOMAIN_ID', str(random.randint(1, 101)))
    os.environ['ROS_AUTOMATIC_DISCOVERY_RANGE'] = 'LOCALHOST'
    records = []
    with tempfile.TemporaryDirectory(prefix='bench_sim_closed_loop_') as tmp:
        for case in args.cases:
            duration = args.duration or (5.0 if CASES[case][1] > 1 else 10.0)
            record = run_case(case, duration, Path(tmp))
            print(json.dumps(record), flush=True)
            records.append(record)
    merge(Path(args.out), records)
    print(f'merged into {args.out}')
    return 0


if __name__ == '__main__':
    sys.exit(main())
