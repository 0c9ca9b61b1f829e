"""SIGKILL benchmark: what a hard-killed recording keeps of what it wrote.

A child process records bridge-like traffic at 120 Hz of wall time: per
period and robot an Odometry (``OdometryCdr``) and a TwistStamped command, per
period ``/clock`` and ``/tf``, and a MarkerArray of 10 outlines once a second.
It counts the messages it has written in shared memory.  After ``--seconds``
the parent SIGKILLs it, reads the bag (no footer, no metadata.yaml) with
``BagReader`` and deserializes every message (rclpy, ``/tf`` with rosbags'
Jazzy types).  Per run: ``fraction`` = recovered / written, ``lost_s`` = the
recording time the lost messages span (the open chunk), ``deserialized`` =
whether every recovered message deserialized.

Writers: ``recorder`` is ``BagRecorder`` with its defaults (chunks finished at
1 MiB or, by the next write, after 1 s); ``rosbags`` is rosbags' rosbag2
``Writer`` (MCAP, zstd chunks), which finishes a chunk only at 1 MiB.  Every
case runs ``--repeats`` times R, run j killing the writer ``seconds + (j +
1/2) / R`` s after it starts recording, so that the kills spread over the
recorder's 1 s flush cycle; the table gives the worst and the median run, the
JSON every run.  Results: a table on stdout and ``bench/results/bag_kill.json``.

    .venv/bin/python bench/bench_bag_kill.py [--seconds 3 10] [--robots 1 4] [--repeats 3]
"""
import argparse
import multiprocessing
import os
import signal
import statistics
import tempfile
import time
from pathlib import Path

from bench_io import require_installed_checkout, write_records
from builtin_interfaces.msg import Time
from geometry_msgs.msg import Point, TwistStamped
from nav_msgs.msg import Odometry
from rclpy.qos import QoSProfile, ReliabilityPolicy
from rclpy.serialization import deserialize_message, serialize_message
from rosbags.interfaces import (
    Qos,
    QosDurability,
    QosHistory,
    QosLiveliness,
    QosReliability,
    QosTime,
)
from rosbags.rosbag2 import CompressionFormat, CompressionMode, StoragePlugin, Writer
from rosbags.typesys import get_typestore, Stores
from rosgraph_msgs.msg import Clock
from visualization_msgs.msg import Marker, MarkerArray

from sim_bridge.bag_reader import BagReader, message_class
from sim_bridge.cdr import OdometryCdr, tf_message_cdr, TF_MESSAGE_TYPE
from sim_bridge.recorder import BagRecorder

REPO = Path(__file__).resolve().parents[1]
RESULTS = REPO / 'bench' / 'results' / 'bag_kill.json'
RATE_HZ = 120.0
QOS = QoSProfile(depth=10, reliability=ReliabilityPolicy.RELIABLE)
JAZZY = get_typestore(Stores.ROS2_JAZZY)


class RecorderSink:
    """``BagRecorder`` with its default chunking."""

    def __init__(self, path):
        """Create the bag."""
        self.recorder = BagRecorder(path)

    def add(self, topic, msg_type):
        """Register a topic; return its handle."""
        self.recorder.add_topic(topic, msg_type, QOS)
        return topic

    def write(self, handle, data, t_ns):
        """Record CDR bytes."""
        self.recorder.write_serialized(handle, data, t_ns)


class RosbagsSink:
    """rosbags' rosbag2 ``Writer``, MCAP storage with zstd chunks."""

    def __init__(self, path):
        """Create and open the bag."""
        self.writer = Writer(path, version=9, storage_plugin=StoragePlugin.MCAP)
        self.writer.set_compression(CompressionMode.STORAGE, CompressionFormat.ZSTD)
        self.writer.open()
        zero = QosTime(0, 0)
        self.qos = Qos(QosHistory.KEEP_LAST, 10, QosReliability.RELIABLE,
                       QosDurability.VOLATILE, zero, zero, QosLiveliness.AUTOMATIC, zero, False)

    def add(self, topic, msg_type):
        """Register a topic; return its connection."""
        name = msg_type if isinstance(msg_type, str) else (
            f'{msg_type.__module__.split(".")[0]}/msg/{msg_type.__name__}')
        return self.writer.add_connection(topic, name, typestore=JAZZY,
                                          offered_qos_profiles=[self.qos])

    def write(self, handle, data, t_ns):
        """Record CDR bytes."""
        self.writer.write(handle, t_ns, data)


SINKS = {'recorder': RecorderSink, 'rosbags': RosbagsSink}


def markers():
    """Return a MarkerArray of 10 square LINE_STRIP outlines."""
    array = MarkerArray()
    for k in range(10):
        marker = Marker(ns='obstacles', id=k, type=Marker.LINE_STRIP, action=Marker.ADD)
        marker.header.frame_id = 'world'
        marker.points = [Point(x=2.0 * k + x, y=y) for x, y in
                         ((0, 0), (1, 0), (1, 1), (0, 1), (0, 0))]
        array.markers.append(marker)
    return array


def record(sink_name, path, robots, written, last_period, ready):
    """Child: record until killed; ``written`` and ``last_period`` follow every write."""
    sink = SINKS[sink_name](path)
    names = [f'a1_{i}' for i in range(robots)]
    odom = [(sink.add(f'/{name}/odom', Odometry), OdometryCdr('world', f'{name}/base_link'))
            for name in names]
    commands = [sink.add(f'/{name}/cmd_vel_out', TwistStamped) for name in names]
    obstacles = sink.add('/a1_0/obstacles', MarkerArray)
    clock, tf = sink.add('/clock', Clock), sink.add('/tf', TF_MESSAGE_TYPE)
    marker_bytes = serialize_message(markers())
    period_ns = round(1e9 / RATE_HZ)
    ready.set()
    start, k = time.monotonic(), 0
    while True:
        t_ns = k * period_ns
        sec, nanosec = divmod(t_ns, 10 ** 9)
        stamp = Time(sec=sec, nanosec=nanosec)
        transforms = []
        for i, ((handle, packer), command) in enumerate(zip(odom, commands)):
            pose = (0.01 * k, float(i), 0.0, 0.0, 0.0, 0.0, 1.0)
            sink.write(handle, packer.pack(sec, nanosec, pose, (0.5, 0, 0, 0, 0, 0)), t_ns)
            msg = TwistStamped()
            msg.header.stamp, msg.twist.linear.x = stamp, 0.5
            sink.write(command, serialize_message(msg), t_ns)
            transforms.append((sec, nanosec, 'world', f'{names[i]}/base_link', pose[:3],
                               pose[3:]))
        sink.write(clock, serialize_message(Clock(clock=stamp)), t_ns)
        sink.write(tf, tf_message_cdr(transforms), t_ns)
        count = 2 * robots + 2
        if k % round(RATE_HZ) == 0:
            sink.write(obstacles, marker_bytes, t_ns)
            count += 1
        written.value += count
        last_period.value = k
        k += 1
        time.sleep(max(0.0, start + k / RATE_HZ - time.monotonic()))


def deserialized(message):
    """Deserialize one raw BagMessage; return True if it worked."""
    try:
        if message.type_name == TF_MESSAGE_TYPE:
            JAZZY.deserialize_cdr(message.message, TF_MESSAGE_TYPE)
        else:
            deserialize_message(message.message, message_class(message.type_name))
    except Exception:  # any failure to decode counts against the bag
        return False
    return True


def run(sink_name, robots, seconds, workdir):
    """Record for ``seconds`` s, SIGKILL the writer, read back; return the run's record."""
    context = multiprocessing.get_context('spawn')
    written, last_period = context.Value('q', 0, lock=False), context.Value('q', -1, lock=False)
    ready = context.Event()
    path = Path(tempfile.mkdtemp(dir=workdir)) / 'bag'
    child = context.Process(target=record,
                            args=(sink_name, str(path), robots, written, last_period, ready))
    child.start()
    if not ready.wait(60.0):
        child.kill()
        raise RuntimeError('the writer did not start')
    time.sleep(seconds)
    os.kill(child.pid, signal.SIGKILL)
    child.join()
    reader = BagReader(path)
    recovered = list(reader.messages(raw=True))
    last_recovered = max((m.log_time_ns for m in recovered), default=-1)
    period_ns = round(1e9 / RATE_HZ)
    lost_periods = last_period.value - (last_recovered // period_ns if recovered else -1)
    return {'bench': 'bag_kill', 'writer': sink_name, 'robots': robots,
            'kill_after_s': round(seconds, 3), 'rate_hz': RATE_HZ, 'written': written.value,
            'recovered': len(recovered),
            'fraction': round(len(recovered) / written.value, 4) if written.value else None,
            'lost_s': round(lost_periods / RATE_HZ, 3),
            'file_bytes': sum(f.stat().st_size for f in reader.files),
            'deserialized': all(deserialized(m) for m in recovered),
            'metadata_yaml': (path / 'metadata.yaml').exists()}


def main(argv=None):
    """Run every case; print the table and write the JSON."""
    parser = argparse.ArgumentParser(description=__doc__.split('\n')[0])
    parser.add_argument('--seconds', type=float, nargs='+', default=[3.0, 10.0])
    parser.add_argument('--robots', type=int, nargs='+', default=[1, 4])
    parser.add_argument('--writers', nargs='+', choices=sorted(SINKS), default=sorted(SINKS))
    parser.add_argument('--repeats', type=int, default=3)
    parser.add_argument('--out', type=Path, default=RESULTS)
    args = parser.parse_args(argv)
    require_installed_checkout()
    records = []
    print(f'{"writer":>9} {"robots":>6} {"kill s":>6} {"written":>8} {"fraction min":>12} '
          f'{"median":>7} {"lost s max":>10} {"all decode":>10}')
    with tempfile.TemporaryDirectory() as workdir:
        for writer in args.writers:
            for robots in args.robots:
                for seconds in args.seconds:
                    runs = [run(writer, robots, seconds + (j + 0.5) / args.repeats, workdir)
                            for j in range(args.repeats)]
                    records += runs
                    fractions = [r['fraction'] for r in runs]
                    print(f'{writer:>9} {robots:>6} {f"{seconds:g}+":>6} '
                          f'{int(statistics.median(r["written"] for r in runs)):>8} '
                          f'{min(fractions):>12.1%} {statistics.median(fractions):>7.1%} '
                          f'{max(r["lost_s"] for r in runs):>10.2f} '
                          f'{str(all(r["deserialized"] for r in runs)):>10}', flush=True)
    write_records(records, args.out)


if __name__ == '__main__':
    main()
