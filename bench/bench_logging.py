"""Logging cost on the control path: rclpy's logger vs ``polyc2bf_ros.loop_log.LoopLogger``.

Each run is a fresh process that imports what ``safety_filter`` imports, starts rclpy and
a node, then per logger logs from one call site with a 60 s throttle: the first call
(emitted; the console goes to /dev/null) and ``--calls`` more within that window (all
suppressed, as in a control loop that reports one fault every step).  Both loggers write
through the same rcutils function; the difference is how the caller is found.

    .venv/bin/python bench/bench_logging.py [--runs 5] [--calls 2000]

Table: medians over the runs, in milliseconds.  Results: ``bench/results/logging.json``.
"""
import argparse
import json
import statistics
import subprocess
import sys
import time
from pathlib import Path

from bench_io import require_installed_checkout, write_records

REPO = Path(__file__).resolve().parents[1]
RESULTS = REPO / 'bench' / 'results' / 'logging.json'


def _rclpy_site(logger):
    return logger.error('bench: a fault reported every step', throttle_duration_sec=60.0)


def _loop_site(logger):
    return logger.error('bench: a fault reported every step', throttle_s=60.0)


def measure(calls):
    """In this process: first-call and per-suppressed-call times [ms] of both loggers."""
    import rclpy

    import polyc2bf_ros.safety_filter_node  # noqa: F401  (the node's module set)
    from polyc2bf_ros.loop_log import LoopLogger

    rclpy.init()
    node = rclpy.create_node('bench_logging')
    result = {}
    for name, logger, site in (('rclpy', node.get_logger(), _rclpy_site),
                               ('loop_log', LoopLogger(node.get_logger()), _loop_site)):
        start = time.perf_counter()
        assert site(logger)
        first = time.perf_counter() - start
        start = time.perf_counter()
        suppressed = sum(not site(logger) for _ in range(calls))
        per_call = (time.perf_counter() - start) / calls
        assert suppressed == calls, 'a call inside the throttle window was emitted'
        result[name] = {'first_ms': first * 1e3, 'per_call_ms': per_call * 1e3}
    node.destroy_node()
    rclpy.try_shutdown()
    return result


def main(argv=None):
    """Run ``--runs`` fresh processes; print the medians and write the records."""
    parser = argparse.ArgumentParser(description=__doc__.split('\n')[0])
    parser.add_argument('--role', choices=['parent', 'child'], default='parent')
    parser.add_argument('--runs', type=int, default=5)
    parser.add_argument('--calls', type=int, default=2000)
    args = parser.parse_args(argv)
    if args.role == 'child':
        print(json.dumps(measure(args.calls)), flush=True)
        return 0
    require_installed_checkout()
    runs = []
    for _ in range(args.runs):
        out = subprocess.run([sys.executable, __file__, '--role', 'child', '--calls',
                              str(args.calls)], cwd=REPO, check=True, text=True,
                             stdout=subprocess.PIPE, stderr=subprocess.DEVNULL).stdout
        runs.append(json.loads(out.strip().splitlines()[-1]))
    records = []
    print(f'{"logger":<10}{"first call ms":>15}{"suppressed call ms":>20}')
    for name in ('rclpy', 'loop_log'):
        first = statistics.median(r[name]['first_ms'] for r in runs)
        per_call = statistics.median(r[name]['per_call_ms'] for r in runs)
        print(f'{name:<10}{first:>15.3f}{per_call:>20.4f}')
        records.append({'bench': 'logging', 'logger': name, 'runs': args.runs,
                        'calls': args.calls, 'first_call_ms': first,
                        'suppressed_call_ms': per_call})
    write_records(records, RESULTS)
    return 0


if __name__ == '__main__':
    sys.exit(main())
