"""DDS isolation probe, run only by ``test_dds_isolation.py`` in a pytest sub-session.

Not collected by the main suite (no ``test_`` prefix).  It lives in ``test/`` so
that ``test/conftest.py`` applies to it exactly as it does to every real test:
each pytest(-xdist) process gets its ``ROS_DOMAIN_ID`` and
``ROS_AUTOMATIC_DISCOVERY_RANGE=LOCALHOST`` from there and from nowhere else.

Each probe creates a real rclpy node that publishes ``<token>:<probe id>:<seq>``
on ``isolation_probe`` at about 50 Hz and subscribes to the same topic.  The
probes meet through files in ``POLYC2BF_PROBE_DIR`` before they publish and
again before they stop, so they certainly publish at the same time, then write
what they heard to ``result-<probe id>.json`` and check it against
``POLYC2BF_PROBE_EXPECT``: ``isolated`` (none of a sibling's messages) or
``shared`` (the positive control: siblings in one domain must hear each other).

Nothing waits on wall time alone: a probe publishes for at least RUN_SECONDS and
until every peer has started and it heard itself (``shared``: and every peer,
however long discovery takes on a busy machine), keeps publishing until every
peer is done, then drains what is still on its way.  The timeouts only turn a
hang into a failure.
"""
import json
import os
import time
from pathlib import Path

import rclpy
from rclpy.executors import SingleThreadedExecutor
from rclpy.qos import QoSProfile, ReliabilityPolicy
from std_msgs.msg import String

TOPIC = 'isolation_probe'
RATE_HZ = 50.0
RUN_SECONDS = 2.0
RENDEZVOUS_TIMEOUT_S = 60.0
HEAR_TIMEOUT_S = 60.0


def _rendezvous(directory, stage, me, peers, spin):
    """Announce ``stage`` for ``me`` and wait (spinning) until every peer announced it."""
    (directory / f'{stage}-{me}').write_text(str(time.time()))
    deadline = time.monotonic() + RENDEZVOUS_TIMEOUT_S
    while not all((directory / f'{stage}-{peer}').exists() for peer in peers):
        if time.monotonic() > deadline:
            missing = [p for p in peers if not (directory / f'{stage}-{p}').exists()]
            raise TimeoutError(f'probe {me}: peers {missing} never reached {stage!r}')
        spin(0.01)


def test_isolation_probe():
    """Publish and listen on ``isolation_probe``; record and check what was heard."""
    directory = Path(os.environ['POLYC2BF_PROBE_DIR'])
    me = os.environ.get('POLYC2BF_PROBE_ID') or os.environ['PYTEST_XDIST_WORKER']
    peers = os.environ['POLYC2BF_PROBE_PEERS'].split(',')
    token = os.environ['POLYC2BF_PROBE_TOKEN']
    expect = os.environ['POLYC2BF_PROBE_EXPECT']
    assert me in peers and expect in ('isolated', 'shared')

    context = rclpy.Context()
    rclpy.init(context=context)
    received = []
    sent = 0
    try:
        node = rclpy.create_node(f'isolation_probe_{me}', context=context)
        qos = QoSProfile(depth=200, reliability=ReliabilityPolicy.RELIABLE)
        node.create_subscription(String, TOPIC, lambda msg: received.append(msg.data), qos)
        publisher = node.create_publisher(String, TOPIC, qos)
        executor = SingleThreadedExecutor(context=context)
        executor.add_node(node)

        def spin(seconds):
            executor.spin_once(timeout_sec=seconds)

        def heard(prefix):
            return any(m.startswith(prefix) for m in received)

        def publish_and_spin(seconds):
            nonlocal sent, next_pub
            if time.monotonic() >= next_pub:
                publisher.publish(String(data=f'{token}:{me}:{sent}'))
                sent += 1
                next_pub += 1.0 / RATE_HZ
            spin(min(seconds, max(0.0, next_pub - time.monotonic())))

        _rendezvous(directory, 'ready', me, peers, spin)
        start = time.time()
        (directory / f'started-{me}').write_text(str(start))
        wanted = [f'{token}:{me}:'] + ([f'{token}:{p}:' for p in peers if p != me]
                                       if expect == 'shared' else [])
        t0 = next_pub = time.monotonic()
        while time.monotonic() - t0 < RUN_SECONDS or not (
                all((directory / f'started-{p}').exists() for p in peers)
                and all(heard(prefix) for prefix in wanted)):
            if time.monotonic() - t0 > HEAR_TIMEOUT_S:
                break  # the asserts below say what was missing
            publish_and_spin(0.02)
        end = time.time()
        # Keep publishing (a peer may still wait to hear us) until every peer is done too.
        _rendezvous(directory, 'done', me, peers, publish_and_spin)
        # Drain: until all of our own messages are in, or none has come for a second.
        quiet_since, count = time.monotonic(), len(received)
        while (sum(m.startswith(f'{token}:{me}:') for m in received) < sent
               and time.monotonic() - quiet_since < 1.0):
            spin(0.02)
            if len(received) > count:
                quiet_since, count = time.monotonic(), len(received)
        for _ in range(10):
            spin(0.02)
        domain_id = context.get_domain_id()
        executor.shutdown()
        node.destroy_node()
    finally:
        rclpy.shutdown(context=context)

    own = sum(1 for m in received if m.startswith(f'{token}:{me}:'))
    siblings = {p: sum(1 for m in received if m.startswith(f'{token}:{p}:'))
                for p in peers if p != me}
    foreign = [m for m in received if not m.startswith(f'{token}:')]
    record = {
        'probe': me,
        'pid': os.getpid(),
        'xdist_worker': os.environ.get('PYTEST_XDIST_WORKER'),
        'env_domain_id': os.environ.get('ROS_DOMAIN_ID'),
        'rclpy_domain_id': domain_id,
        'discovery_range': os.environ.get('ROS_AUTOMATIC_DISCOVERY_RANGE'),
        'start': start,
        'end': end,
        'sent': sent,
        'own_received': own,
        'sibling_received': siblings,
        'foreign_received': len(foreign),
    }
    (directory / f'result-{me}.json').write_text(json.dumps(record, indent=1))

    assert str(domain_id) == os.environ['ROS_DOMAIN_ID'], record
    assert sent > 0, record
    assert own >= sent * 0.5, f'probe did not hear its own messages: {record}'
    if expect == 'isolated':
        assert not any(siblings.values()), f'heard another worker: {record}'
    else:
        assert all(siblings.values()), f'positive control: did not hear peers: {record}'
