"""Benchmark the closed loop in lockstep: real-time factor, CPU per period, bridge memory.

Usage: python bench/bench_sim_closed_loop.py [--cases ...] [--floor] [--out bench/results/sim.json]

Per case, as separate processes over real DDS (loopback, a private
ROS_DOMAIN_ID): ``sim_bridge`` (lockstep, recording its bag) and per robot a
``nominal_controller`` and a ``safety_filter`` (``trigger: command``), or only
the nominal controller wired straight to the robot for the ``_no_filter`` case.
real_time_factor = simulated time / wall time of the bridge's loop after every
robot answered the first period (from its metrics JSON; the bridge waits up to
30 s for each period's commands, so a starved robot slows the run rather than
dropping out); ``cpu_ms_per_period``
= CPU time (user + system, /proc) each kind of process spent per control period
over that loop, the number that is fair on a shared machine (wall time there
includes waiting for other jobs); rss_mb = the bridge's peak resident set
(VmHWM).  The bridge runs with its defaults: it records the filters'
``~/markers`` (which a filter renders only while someone listens) unless
``--no-filter-markers``.

``--floor`` measures what DDS alone costs per lockstep period: a driver
publishes an Odometry and waits for the answer that has passed through a chain
of 1..3 relay processes (each takes the message raw and publishes a
TwistStamped: one hop each, as odom -> nominal -> filter -> bridge), 3000
rounds after warm-up.  Both sides wait on lean rcl wait sets, so this is the
bound no Python node of this design can beat: 1 / (120 Hz * round time).

Records (``transport: dds``) are merged into ``--out``: this benchmark's
earlier records of the same cases are replaced; the world-alone and in-process
records of bench/bench_sim.py are kept.
"""
import argparse
import json
import os
import random
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np
import yaml
from bench_io import require_installed_checkout

from sim_bridge.launcher import stop_processes
from sim_bridge.scenario import load_scenario

REPO = Path(__file__).resolve().parents[1]
CONTROL_RATE = 120.0  # the bridge's effective rate for 240 Hz physics / 100 Hz control
# One A1 crossing 50 seeded random polygons (bench/bench_sim.py's case, as a file).
QUADRUPED_50 = {
    'name': 'quadruped_50_obstacles', 'duration': 10.0, 'seed': 7,
    'robots': [{'name': 'a1', 'type': 'quadruped', 'start': [0, 0, 0], 'goal': [20, 0]}],
    'random_obstacles': {'count': 50, 'region': [[2, -8], [18, 8]], 'size': [0.4, 1.0],
                         'height': [0.5, 1.5], 'clearance': 1.0, 'spacing': 0.9}}
# case: (scenario dict or path, robots, with filter)
CASES = {
    'quadruped_50_obstacles': (QUADRUPED_50, 1, True),
    'quadruped_50_obstacles_no_filter': (QUADRUPED_50, 1, False),
    'crazyflie_pillars': (str(REPO / 'config' / 'scenarios' / 'quadrotor_pillars.yaml'), 1,
                          True),
    # Eight A1s abreast in lanes 1.5 m apart, each seeing the other seven.
    'quadrupeds_8': ({
        'name': 'quadrupeds_8', 'duration': 5.0,
        'robots': [{'name': f'a1_{i}', 'type': 'quadruped', 'start': [0.0, 1.5 * i, 0.0],
                    'goal': [20.0, 1.5 * i]} for i in range(8)]}, 8, True),
}
FLOOR_ROUNDS = 3000


def _ros(module, *args):
    return [sys.executable, '-m', module, '--ros-args', *args]


def robot_commands(robot, with_filter=True):
    """Return the nominal controller (and filter) command lines of one scenario robot."""
    ns = ['-r', f'__ns:=/{robot["name"]}']
    goal = '[' + ','.join(str(float(g)) for g in robot['goal']) + ']'
    quadruped = robot['type'] == 'quadruped'
    nominal = _ros('sim_bridge.nominal_controller_node', *ns, '-p',
                   f'robot_type:={robot["type"]}', '-p', f'goal:={goal}')
    if not with_filter:
        return [nominal + ['-r', 'cmd_vel_in:=cmd_vel_out' if quadruped
                           else 'wrench_in:=wrench_out']]
    if quadruped:
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


def cpu_seconds(pid):
    """Return the user + system CPU time [s] of ``pid`` so far, or None once it has exited."""
    try:
        fields = Path(f'/proc/{pid}/stat').read_text().rsplit(')', 1)[1].split()
    except OSError:
        return None
    return (int(fields[11]) + int(fields[12])) / os.sysconf('SC_CLK_TCK')


def run_case(case, duration, workdir, record_filter_markers):
    """Run one case; return its record."""
    spec, robots, with_filter = CASES[case]
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
                  'startup_timeout:=120.0', '-p', 'lockstep_timeout:=30.0', '-p',
                  f'record_filter_markers:={str(record_filter_markers).lower()}')
    log = open(workdir / f'{case}.log', 'w')
    children = [(command[command.index('-m') + 1].rsplit('.', 1)[1],
                 subprocess.Popen(command, env=env, stdout=log, stderr=subprocess.STDOUT))
                for robot in robot_list for command in robot_commands(robot, with_filter)]
    proc = subprocess.Popen(bridge, env=env, stdout=log, stderr=subprocess.STDOUT)
    processes = children + [('bridge_node', proc)]
    rss, samples = 0.0, []
    try:
        while proc.poll() is None:
            rss = max(rss, peak_rss_mb(proc.pid) or 0.0)
            cpu = [cpu_seconds(p.pid) for _, p in processes]
            if None not in cpu:
                samples.append((time.monotonic(), cpu))
            time.sleep(0.1)
    finally:
        stop_processes([child for _, child in processes], timeout=10)
    result = json.loads(metrics.read_text())
    periods = result['sim_time_s'] * result['control_rate']
    # CPU over the loop: from the sample nearest its start (end - wall) to the last one.
    start = samples[-1][0] - result['wall_time_s']
    first = min(samples, key=lambda sample: abs(sample[0] - start))
    cpu_ms = {}
    for (kind, _), before, after in zip(processes, first[1], samples[-1][1]):
        cpu_ms[kind] = cpu_ms.get(kind, 0.0) + 1e3 * (after - before) / periods
    return {'bench': 'sim', 'case': case, 'robots': robots, 'closed_loop': True,
            'transport': 'dds',
            'filter': with_filter, 'filter_markers_recorded': record_filter_markers,
            'real_time_factor': result['real_time_factor'], 'rss_mb': round(rss, 1),
            'sim_seconds': result['sim_time_s'], 'wall_seconds': result['wall_time_s'],
            'wall_ms_per_period': round(1e3 * result['wall_time_s'] / periods, 3),
            'cpu_ms_per_period': {k: round(v, 3) for k, v in cpu_ms.items()},
            'control_rate': result['control_rate'], 'completed': result['completed'],
            'lockstep_timeouts': sum(result['lockstep_timeouts'].values()),
            'collisions': sum(r['collision'] for r in result['robots'].values()),
            'load_average_1m': round(os.getloadavg()[0], 2), 'cpus': os.cpu_count()}


def _lean_node(name):
    """Return (rclpy, node) with rclpy initialised; the caller shuts it down."""
    import rclpy
    rclpy.init()
    return rclpy, rclpy.create_node(name)


def relay(source, target):
    """Relay process of ``--floor``: answer each message on ``source`` on ``target`` at once."""
    from geometry_msgs.msg import TwistStamped
    from nav_msgs.msg import Odometry
    from rclpy.serialization import serialize_message

    from sim_bridge.bridge_node import COMMAND_QOS
    from sim_bridge.inbox import Inbox
    rclpy, node = _lean_node(f'relay_{target}')
    publisher = node.create_publisher(TwistStamped, target, COMMAND_QOS)
    answer = serialize_message(TwistStamped())
    node.create_subscription(Odometry if source == 'odom' else TwistStamped, source,
                             lambda data: publisher.publish(answer), COMMAND_QOS, raw=True)
    inbox = Inbox(node)
    try:
        while rclpy.ok():
            inbox.wait(1.0)
    except KeyboardInterrupt:
        pass
    finally:
        rclpy.try_shutdown()


def floor(hops, workdir):
    """Measure ``FLOOR_ROUNDS`` lockstep rounds through ``hops`` relays; return the record."""
    from geometry_msgs.msg import TwistStamped
    from nav_msgs.msg import Odometry
    from rclpy.serialization import serialize_message

    from sim_bridge.bridge_node import COMMAND_QOS
    from sim_bridge.inbox import Inbox
    chain = ['odom', *(f'hop_{i}' for i in range(1, hops)), 'answer']
    env = {**os.environ, 'PYTHONPATH': str(REPO), 'ROS_LOG_DIR': str(workdir / 'log')}
    relays = [subprocess.Popen([sys.executable, __file__, '--relay', source, target], env=env,
                               stdout=subprocess.DEVNULL)
              for source, target in zip(chain[:-1], chain[1:])]
    rclpy, node = _lean_node('floor_driver')
    try:
        publisher = node.create_publisher(Odometry, 'odom', COMMAND_QOS)
        answers = []
        node.create_subscription(TwistStamped, 'answer', answers.append, COMMAND_QOS, raw=True)
        inbox = Inbox(node)
        odometry = serialize_message(Odometry())

        def round_trip(timeout):
            answers.clear()
            publisher.publish(odometry)
            deadline = time.monotonic() + timeout
            while not answers and time.monotonic() < deadline:
                inbox.wait(deadline - time.monotonic())
            return bool(answers)

        deadline = time.monotonic() + 60.0
        while not round_trip(0.5) and time.monotonic() < deadline:
            pass  # discovery
        for _ in range(200):
            round_trip(1.0)
        times = []
        for _ in range(FLOOR_ROUNDS):
            tick = time.perf_counter()
            round_trip(1.0)
            times.append(time.perf_counter() - tick)
    finally:
        rclpy.try_shutdown()
        stop_processes(relays, timeout=10)
    times = 1e3 * np.array(times)
    return {'bench': 'sim', 'case': f'dds_floor_{hops}_hops', 'closed_loop': True,
            'transport': 'dds',
            'hops': hops, 'rounds': FLOOR_ROUNDS,
            'round_ms_mean': round(float(times.mean()), 3),
            'round_ms_p50': round(float(np.percentile(times, 50)), 3),
            'round_ms_p99': round(float(np.percentile(times, 99)), 3),
            'max_real_time_factor': round(1e3 / CONTROL_RATE / float(times.mean()), 1),
            'load_average_1m': round(os.getloadavg()[0], 2), 'cpus': os.cpu_count()}


def merge(out, records):
    """Replace this benchmark's records of the same cases in ``out``, keep all others."""
    existing = json.loads(out.read_text()) if out.exists() else []
    cases = {r['case'] for r in records}
    kept = [r for r in existing if not (r.get('transport') == 'dds' and r.get('case') in cases)]
    out.parent.mkdir(parents=True, exist_ok=True)
    out.write_text(json.dumps(kept + records, indent=1) + '\n')


def print_row(record):
    """Print one record as a table row."""
    if 'hops' in record:
        print(f'{record["case"]:<34} round mean {record["round_ms_mean"]:.3f} ms, p50 '
              f'{record["round_ms_p50"]:.3f} ms, p99 {record["round_ms_p99"]:.3f} ms -> at most '
              f'{record["max_real_time_factor"]:.1f}x  (load {record["load_average_1m"]})',
              flush=True)
        return
    cpu = ', '.join(f'{k} {v:.2f}' for k, v in record['cpu_ms_per_period'].items())
    print(f'{record["case"]:<34} {record["real_time_factor"]:>6.2f}x  '
          f'{record["wall_ms_per_period"]:>7.2f} ms/period wall; CPU ms/period: {cpu}; '
          f'RSS {record["rss_mb"]:.0f} MB; timeouts {record["lockstep_timeouts"]} '
          f'(load {record["load_average_1m"]})', flush=True)


def main(argv=None):
    """Run the cases (and the DDS floor), print them and merge them into the results file."""
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument('--cases', nargs='*', choices=list(CASES), default=list(CASES))
    parser.add_argument('--duration', type=float, default=None,
                        help='sim seconds per case (default: 10 for one robot, 5 for eight)')
    parser.add_argument('--no-filter-markers', action='store_true',
                        help="the bridge does not subscribe to (record) the filters' markers")
    parser.add_argument('--floor', action='store_true',
                        help='also measure the DDS floor of 1, 2 and 3 hops per period')
    parser.add_argument('--relay', nargs=2, metavar=('SOURCE', 'TARGET'), help=argparse.SUPPRESS)
    parser.add_argument('--out', default=str(REPO / 'bench' / 'results' / 'sim.json'))
    args = parser.parse_args(argv)
    if args.relay:
        relay(*args.relay)
        return 0
    require_installed_checkout()
    os.environ.setdefault('ROS_DOMAIN_ID', str(random.randint(1, 101)))
    os.environ['ROS_AUTOMATIC_DISCOVERY_RANGE'] = 'LOCALHOST'
    records = []
    with tempfile.TemporaryDirectory(prefix='bench_sim_closed_loop_') as tmp:
        for case in args.cases:
            duration = args.duration or (5.0 if CASES[case][1] > 1 else 10.0)
            records.append(run_case(case, duration, Path(tmp), not args.no_filter_markers))
            print_row(records[-1])
        for hops in (1, 2, 3) if args.floor else ():
            records.append(floor(hops, Path(tmp)))
            print_row(records[-1])
    merge(Path(args.out), records)
    print(f'merged into {args.out}')
    return 0


if __name__ == '__main__':
    sys.exit(main())
