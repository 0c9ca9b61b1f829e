"""DDS isolation between parallel tests, proved with real rclpy traffic.

``test/conftest.py`` gives every pytest-xdist worker its own ``ROS_DOMAIN_ID``
and keeps discovery on loopback.  These tests run ``dds_isolation_probe.py`` in
a pytest sub-session so that the conftest applies to it as it does to the suite:

* two xdist workers publish on the same topic at the same time and neither
  hears the other (while each hears itself);
* the positive control: two pytest processes that conftest puts into the same
  domain do hear each other, so the first result is not a probe that hears
  nothing across processes;
* a child process started by a test inherits the domain and the discovery range.
"""
import json
import os
import random
import subprocess
import sys
import time
import uuid
from pathlib import Path

import pytest

REPO = Path(__file__).resolve().parents[1]
PROBE = REPO / 'test' / 'dds_isolation_probe.py'
# Must match MAX_WORKERS in test/conftest.py: the outer session owns the domains
# base .. base + MAX_WORKERS - 1; sub-sessions pick their base outside that block.
MAX_WORKERS = 16
SUBSESSION_TIMEOUT_S = 180


def _outer_domain_block():
    base = int(os.environ['POLYC2BF_TEST_DOMAIN_BASE'])
    return range(base, base + MAX_WORKERS)


def _free_subsession_base(workers):
    """Pick a domain base whose ``workers`` domains avoid this session's block."""
    taken = _outer_domain_block()
    candidates = [b for b in range(1, 100 - MAX_WORKERS + 1)
                  if not any(d in taken for d in range(b, b + workers))]
    return random.choice(candidates)


def _probe_env(directory, base, peers, expect, token, probe_id=None):
    env = {k: v for k, v in os.environ.items()
           if not k.startswith(('PYTEST_', 'POLYC2BF_', 'COV_CORE_'))
           and k not in ('ROS_DOMAIN_ID', 'ROS_AUTOMATIC_DISCOVERY_RANGE')}
    env.update({
        'POLYC2BF_TEST_DOMAIN_BASE': str(base),
        'POLYC2BF_PROBE_DIR': str(directory),
        'POLYC2BF_PROBE_PEERS': ','.join(peers),
        'POLYC2BF_PROBE_TOKEN': token,
        'POLYC2BF_PROBE_EXPECT': expect,
    })
    if probe_id is not None:
        env['POLYC2BF_PROBE_ID'] = probe_id
    return env


def _pytest_cmd(*args):
    # A probe stuck past faulthandler_timeout prints every thread's stack to stderr.
    return [sys.executable, '-m', 'pytest', '-p', 'no:cacheprovider', '-q',
            '-o', f'faulthandler_timeout={SUBSESSION_TIMEOUT_S // 2}',
            *args, str(PROBE.relative_to(REPO))]


def _run_probes(commands, attempts=2):
    """Run the probe sub-sessions ``[(argv, env, directory)]`` together; return their outputs.

    A sub-session still running after ``SUBSESSION_TIMEOUT_S`` is killed with the
    others and the round is run again, once (a stuck DDS process is not a wrong
    answer: once in many CI runs a probe hung; its stacks are in the failure text).
    """
    hung = []
    for _ in range(attempts):
        for _, _, directory in commands:
            for stale in directory.glob('*'):
                stale.unlink()
        procs = [subprocess.Popen(argv, cwd=REPO, env=env, stdout=subprocess.PIPE,
                                  stderr=subprocess.PIPE, text=True)
                 for argv, env, _ in commands]
        deadline = time.monotonic() + SUBSESSION_TIMEOUT_S
        streams = {}
        for proc in procs:
            try:
                streams[proc] = proc.communicate(timeout=max(0.0, deadline - time.monotonic()))
            except subprocess.TimeoutExpired:
                pass
        timed_out = len(streams) < len(procs)
        for proc in procs:
            if proc not in streams:
                proc.kill()
                streams[proc] = proc.communicate()
        outputs = [subprocess.CompletedProcess(proc.args, proc.returncode, *streams[proc])
                   for proc in procs]
        if not timed_out:
            return outputs
        hung.append('\n'.join(_output(out) for out in outputs))
    pytest.fail(f'probe sub-sessions hung {attempts} times:\n' + '\n'.join(hung))


def _results(directory, probes):
    found = {p.name for p in directory.glob('result-*.json')}
    assert found == {f'result-{p}.json' for p in probes}, found
    return {p: json.loads((directory / f'result-{p}.json').read_text()) for p in probes}


def _output(proc):
    return f'rc={proc.returncode}\n--- stdout\n{proc.stdout}\n--- stderr\n{proc.stderr}'


@pytest.mark.slow
def test_two_xdist_workers_on_one_topic_do_not_hear_each_other(tmp_path):
    """Two -n 2 workers publish on ``isolation_probe`` together; neither hears the other."""
    base = _free_subsession_base(2)
    workers = ['gw0', 'gw1']
    # --dist each runs the one probe test on both workers, so both certainly run.
    proc, = _run_probes([(_pytest_cmd('-n', '2', '--dist', 'each'),
                          _probe_env(tmp_path, base, workers, 'isolated', uuid.uuid4().hex),
                          tmp_path)])
    assert proc.returncode == 0, _output(proc)
    assert '2 passed' in proc.stdout, _output(proc)

    res = _results(tmp_path, workers)
    for index, worker in enumerate(workers):
        r = res[worker]
        assert r['xdist_worker'] == worker
        assert r['env_domain_id'] == str(base + index), r
        assert r['rclpy_domain_id'] == base + index, r
        assert r['discovery_range'] == 'LOCALHOST', r
        assert r['own_received'] > 0, r
        assert r['sibling_received'] == {w: 0 for w in workers if w != worker}, r
    assert res['gw0']['pid'] != res['gw1']['pid']
    assert res['gw0']['rclpy_domain_id'] != res['gw1']['rclpy_domain_id']
    # Both publish windows overlap: the workers were on the wire at the same time.
    assert max(r['start'] for r in res.values()) < min(r['end'] for r in res.values()), res


@pytest.mark.slow
def test_positive_control_same_domain_processes_hear_each_other(tmp_path):
    """Two pytest processes that conftest puts into one domain do exchange messages."""
    base = _free_subsession_base(1)
    probes = ['a', 'b']
    token = uuid.uuid4().hex
    outputs = _run_probes([
        (_pytest_cmd('-p', 'no:xdist'),
         _probe_env(tmp_path, base, probes, 'shared', token, probe_id=p), tmp_path)
        for p in probes])
    for out in outputs:
        assert out.returncode == 0, _output(out)

    res = _results(tmp_path, probes)
    assert res['a']['rclpy_domain_id'] == res['b']['rclpy_domain_id'] == base, res
    assert res['a']['sibling_received']['b'] > 0, res
    assert res['b']['sibling_received']['a'] > 0, res


def test_child_process_inherits_domain_and_localhost_discovery():
    """A process a test starts (as node tests do) gets this worker's domain on loopback."""
    worker = os.environ.get('PYTEST_XDIST_WORKER', 'gw0')
    expected_domain = int(os.environ['POLYC2BF_TEST_DOMAIN_BASE']) + int(worker[2:])
    keys = ('ROS_DOMAIN_ID', 'ROS_AUTOMATIC_DISCOVERY_RANGE', 'ROS_STATIC_PEERS')
    code = f'import json, os; print(json.dumps({{k: os.environ.get(k) for k in {keys!r}}}))'
    proc = subprocess.run([sys.executable, '-c', code], capture_output=True, text=True,
                          timeout=60, check=True)
    child = json.loads(proc.stdout)
    assert child['ROS_DOMAIN_ID'] == str(expected_domain), child
    assert child['ROS_AUTOMATIC_DISCOVERY_RANGE'] == 'LOCALHOST', child
    assert child['ROS_STATIC_PEERS'] is None, child
