"""MCAP recorder: real bags checked by independent readers (rosbags, mcap) and our replay reader.

rosbags deserializes with nothing but the schemas stored in the bag (its
AnyReader starts from an empty type store), so a message that comes back equal
to the original proves the CDR bytes and the ``ros2msg`` schema independently;
rosbags' own RIHS01 hash of the stored schema must equal the hash rosidl
generated for the installed type.
"""
import array
import json
import os
import select
import signal
import struct
import subprocess
import sys
import tempfile
import threading
import time
from pathlib import Path

import numpy as np
import pytest
import yaml
from builtin_interfaces.msg import Duration as DurationMsg, Time
from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus, KeyValue
from geometry_msgs.msg import Point, Pose, Quaternion, Twist, TwistStamped, Vector3, WrenchStamped
from hypothesis import given, settings, strategies as st
from mcap.reader import make_reader
from nav_msgs.msg import Odometry
from rclpy.duration import Duration, Infinite
from rclpy.qos import DurabilityPolicy, LivelinessPolicy, QoSProfile, ReliabilityPolicy
from rclpy.serialization import serialize_message
from rosbags.highlevel import AnyReader
from rosbags.interfaces import (
    Qos,
    QosDurability,
    QosHistory,
    QosLiveliness,
    QosReliability,
    QosTime,
)
from rosbags.typesys import get_typestore, Stores
from rosgraph_msgs.msg import Clock
from std_msgs.msg import ColorRGBA, Header
from visualization_msgs.msg import Marker, MarkerArray

from sim_bridge.bag_reader import BagReader
from sim_bridge.recorder import BagRecorder, close_on_signals

REPO = Path(__file__).resolve().parents[2]
HELPER = Path(__file__).with_name('record_until_signal.py')
JAZZY = get_typestore(Stores.ROS2_JAZZY)
TF_TYPE = 'tf2_msgs/msg/TFMessage'  # tf2_msgs is not installed here: rosbags' types stand in
RELIABLE = QoSProfile(depth=10, reliability=ReliabilityPolicy.RELIABLE)
LATCHED = QoSProfile(depth=1, reliability=ReliabilityPolicy.RELIABLE,
                     durability=DurabilityPolicy.TRANSIENT_LOCAL)
CLOCK_QOS = QoSProfile(depth=1, reliability=ReliabilityPolicy.BEST_EFFORT,
                       durability=DurabilityPolicy.VOLATILE, deadline=Infinite,
                       liveliness=LivelinessPolicy.AUTOMATIC,
                       liveliness_lease_duration=Duration(seconds=1, nanoseconds=500_000_000))


def type_name(msg_class):
    """Return ``'pkg/msg/Type'`` of an rclpy message class."""
    return f'{msg_class.__module__.split(".")[0]}/msg/{msg_class.__name__}'


def rosidl_hash(name):
    """Return the RIHS01 hash rosidl generated for an installed ``'pkg/msg/Type'``."""
    package, _, short = name.split('/')
    path = Path(sys.prefix) / 'share' / package / 'msg' / f'{short}.json'
    hashes = json.loads(path.read_text())['type_hashes']
    return next(entry['hash_string'] for entry in hashes if entry['type_name'] == name)


def stamp(sec, nanosec=0):
    """Return a Header stamped at ``sec``.``nanosec`` in frame ``map``."""
    return Header(stamp=Time(sec=sec, nanosec=nanosec), frame_id='map')


def odometry(i):
    """Return an Odometry whose every field depends on ``i``."""
    msg = Odometry(header=stamp(10 + i, 250), child_frame_id=f'base_link_{i}')
    msg.pose.pose = Pose(position=Point(x=1.0 + i, y=-2.0, z=0.5),
                         orientation=Quaternion(x=0.0, y=0.0, z=0.6, w=0.8))
    msg.pose.covariance = [0.01 * k + i for k in range(36)]
    msg.twist.twist = Twist(linear=Vector3(x=0.7, y=-0.1 * i, z=0.0),
                            angular=Vector3(x=0.0, y=0.0, z=-0.3))
    msg.twist.covariance = [-0.5 * k for k in range(36)]
    return msg


def marker_array(i):
    """Return a MarkerArray with a coloured LINE_STRIP, a CUBE and a DELETEALL."""
    line = Marker(header=stamp(20 + i), ns='walls', id=3 + i, type=Marker.LINE_STRIP,
                  action=Marker.ADD, text='wall', frame_locked=True)
    line.points = [Point(x=0.0, y=0.0, z=0.0), Point(x=2.0, y=0.0, z=0.0),
                   Point(x=2.0, y=1.5 + i, z=0.0)]
    line.colors = [ColorRGBA(r=1.0, g=0.5, b=0.25, a=1.0)] * 3
    line.scale.x = 0.05
    line.lifetime = DurationMsg(sec=2, nanosec=5)
    cube = Marker(header=stamp(20 + i), ns='boxes', id=7, type=Marker.CUBE,
                  action=Marker.ADD, mesh_resource='package://sim/box.dae')
    cube.pose.position = Point(x=4.0, y=-1.0 * i, z=0.5)
    cube.pose.orientation.w = 1.0
    cube.scale = Vector3(x=1.0, y=0.5, z=1.0)
    cube.color = ColorRGBA(r=0.0, g=0.0, b=1.0, a=0.5)
    return MarkerArray(markers=[line, cube, Marker(action=Marker.DELETEALL)])


def twist_stamped(i):
    """Return a TwistStamped depending on ``i``."""
    return TwistStamped(header=stamp(30 + i), twist=Twist(
        linear=Vector3(x=0.25 * i, y=0.0, z=0.0), angular=Vector3(x=0.0, y=0.0, z=0.1)))


def wrench_stamped(i):
    """Return a WrenchStamped: collective thrust on force.z, body torques."""
    msg = WrenchStamped(header=stamp(40 + i))
    msg.wrench.force.z = 0.3 + 0.01 * i
    msg.wrench.torque = Vector3(x=1e-4, y=-2e-4, z=3e-5 * i)
    return msg


def clock(i):
    """Return a Clock at ``i`` ms."""
    return Clock(clock=Time(sec=i // 1000, nanosec=(i % 1000) * 1_000_000))


def diagnostics(i):
    """Return a DiagnosticArray with a WARN status and key/values."""
    status = DiagnosticStatus(level=DiagnosticStatus.WARN, name='safety_filter: qp',
                              message=f'min h {0.1 * i:.2f}', hardware_id='sim',
                              values=[KeyValue(key='rate_hz', value='999.8'),
                                      KeyValue(key='infeasible', value=str(i))])
    return DiagnosticArray(header=stamp(50 + i), status=[status])


def tf_message(i):
    """Return a rosbags TFMessage (no tf2_msgs Python package here) with two transforms."""
    types = JAZZY.types

    def transform(child, x):
        return types['geometry_msgs/msg/TransformStamped'](
            header=types['std_msgs/msg/Header'](
                stamp=types['builtin_interfaces/msg/Time'](sec=60 + i, nanosec=7),
                frame_id='map'),
            child_frame_id=child,
            transform=types['geometry_msgs/msg/Transform'](
                translation=types['geometry_msgs/msg/Vector3'](x=x, y=1.0, z=0.0),
                rotation=types['geometry_msgs/msg/Quaternion'](x=0.0, y=0.0, z=0.0, w=1.0)))

    return types[TF_TYPE](transforms=[transform('robot0/base_link', 0.5 * i),
                                      transform('robot1/base_link', -1.0)])


# topic: (type, QoS, message builder)
TOPICS = {
    '/robot0/odom': (Odometry, RELIABLE, odometry),
    '/robot0/obstacles': (MarkerArray, LATCHED, marker_array),
    '/robot0/cmd_vel_out': (TwistStamped, RELIABLE, twist_stamped),
    '/robot1/wrench_out': (WrenchStamped, RELIABLE, wrench_stamped),
    '/clock': (Clock, CLOCK_QOS, clock),
    '/diagnostics': (DiagnosticArray, QoSProfile(depth=100), diagnostics),
}
COUNTS = {'/robot0/odom': 5, '/robot0/obstacles': 2, '/robot0/cmd_vel_out': 4,
          '/robot1/wrench_out': 3, '/clock': 6, '/diagnostics': 2, '/tf': 3}
TF_QOS = QoSProfile(depth=100)


def assert_same(expected, actual, where='msg'):
    """Assert two messages (rclpy or rosbags, any mix) hold the same field values exactly."""
    if hasattr(expected, 'get_fields_and_field_types'):
        names = list(expected.get_fields_and_field_types())
    elif hasattr(expected, '__dataclass_fields__'):
        names = list(expected.__dataclass_fields__)
    else:
        names = None
    if names is not None:
        for name in names:
            assert_same(getattr(expected, name), getattr(actual, name), f'{where}.{name}')
    elif isinstance(expected, str):
        assert expected == actual, where
    elif isinstance(expected, (bytes, list, tuple, array.array, np.ndarray)):
        actual = [actual] if isinstance(actual, int) else list(actual)
        assert len(expected) == len(actual), where
        for k, (item, got) in enumerate(zip(expected, actual)):
            assert_same(item, got, f'{where}[{k}]')
    elif isinstance(expected, float):
        assert struct.pack('<d', expected) == struct.pack('<d', got := float(actual)), \
            f'{where}: {expected!r} != {got!r}'
    else:
        assert expected == actual, f'{where}: {expected!r} != {actual!r}'


def rosbags_qos(profile):
    """Return the rosbags ``Qos`` a recorded ``QoSProfile`` must read back as."""
    def qtime(value):
        return QosTime(*divmod(value.nanoseconds, 10 ** 9))

    return Qos(QosHistory[profile.history.name], profile.depth,
               QosReliability[profile.reliability.name], QosDurability[profile.durability.name],
               qtime(profile.deadline), qtime(profile.lifespan),
               QosLiveliness[profile.liveliness.name], qtime(profile.liveliness_lease_duration),
               profile.avoid_ros_namespace_conventions)


def record_known_bag(path, compression='zstd'):
    """Record COUNTS messages per topic (interleaved in time); return {topic: [(t, msg)]}."""
    written = {topic: [] for topic in COUNTS}
    with BagRecorder(path, compression=compression) as recorder:
        for topic, (msg_type, qos, _) in TOPICS.items():
            recorder.add_topic(topic, msg_type, qos)
        recorder.add_topic('/tf', TF_TYPE, TF_QOS)
        t = 1_700_000_000_000_000_000
        for i in range(max(COUNTS.values())):
            for topic, count in COUNTS.items():
                if i >= count:
                    continue
                t += 1_000_000
                if topic == '/tf':
                    msg = tf_message(i)
                    recorder.write_serialized(topic, JAZZY.serialize_cdr(msg, TF_TYPE), t)
                else:
                    msg = TOPICS[topic][2](i)
                    recorder.write(topic, msg, t, publish_time_ns=t - 500)
                written[topic].append((t, msg))
        assert recorder.message_counts == COUNTS
    return written


@pytest.fixture(scope='module')
def known_bag(tmp_path_factory):
    """Record the known bag once; return (bag directory, what was written)."""
    path = tmp_path_factory.mktemp('bags') / 'known'
    return path, record_known_bag(path)


def expected_qos(topic):
    """Return the QoSProfile a topic of the known bag was recorded with."""
    return TF_QOS if topic == '/tf' else TOPICS[topic][1]


def test_bag_directory_layout_is_rosbag2s(known_bag):
    """The directory holds metadata.yaml (version 9) and <name>_0.mcap, as ros2 bag record."""
    path, written = known_bag
    assert sorted(p.name for p in path.iterdir()) == ['known_0.mcap', 'metadata.yaml']
    info = yaml.safe_load((path / 'metadata.yaml').read_text())['rosbag2_bagfile_information']
    assert info['version'] == 9
    assert info['storage_identifier'] == 'mcap'
    assert info['relative_file_paths'] == ['known_0.mcap']
    assert info['message_count'] == sum(COUNTS.values())
    times = [t for messages in written.values() for t, _ in messages]
    assert info['starting_time']['nanoseconds_since_epoch'] == min(times)
    assert info['duration']['nanoseconds'] == max(times) - min(times)
    assert info['files'][0]['message_count'] == sum(COUNTS.values())
    assert (info['compression_format'], info['compression_mode']) == ('', '')
    topics = {t['topic_metadata']['name']: t for t in info['topics_with_message_count']}
    assert {name: t['message_count'] for name, t in topics.items()} == COUNTS
    odom = topics['/robot0/odom']['topic_metadata']
    assert odom['type_description_hash'] == rosidl_hash(type_name(Odometry))
    assert odom['offered_qos_profiles'][0]['reliability'] == 'reliable'


@pytest.mark.parametrize('open_as', ['directory', 'mcap file'])
def test_rosbags_reads_topics_counts_types_qos_and_messages(known_bag, open_as):
    """The rosbags reader opens the bag both ways; every message equals the one written."""
    path, written = known_bag
    target = path if open_as == 'directory' else path / 'known_0.mcap'
    with AnyReader([target]) as reader:
        connections = {c.topic: c for c in reader.connections}
        assert {t: c.msgcount for t, c in connections.items()} == COUNTS
        for topic, connection in connections.items():
            expected_type = TF_TYPE if topic == '/tf' else type_name(TOPICS[topic][0])
            assert connection.msgtype == expected_type
            assert connection.ext.serialization_format == 'cdr'
            assert connection.ext.offered_qos_profiles == [rosbags_qos(expected_qos(topic))]
        read = {topic: [] for topic in COUNTS}
        for connection, t, raw in reader.messages():
            read[connection.topic].append((t, reader.deserialize(raw, connection.msgtype)))
        for topic, messages in written.items():
            assert [t for t, _ in read[topic]] == [t for t, _ in messages], topic
            for (_, original), (_, decoded) in zip(messages, read[topic]):
                assert_same(original, decoded, topic)


def test_stored_schemas_hash_to_the_rosidl_type_hash(known_bag):
    """The RIHS01 rosbags computes from each stored schema equals rosidl's (tf2: rosbags')."""
    path, _ = known_bag
    with AnyReader([path / 'known_0.mcap']) as reader:
        for topic, (msg_type, _, _) in TOPICS.items():
            name = type_name(msg_type)
            assert reader.typestore.hash_rihs01(name) == rosidl_hash(name), topic
        assert reader.typestore.hash_rihs01(TF_TYPE) == JAZZY.hash_rihs01(TF_TYPE)


def test_mcap_library_sees_ros2_profile_schemas_and_compressed_indexed_chunks(known_bag):
    """The mcap reader: ros2 profile, ros2msg schemas, cdr channels, zstd chunks, indexes."""
    path, _ = known_bag
    with open(path / 'known_0.mcap', 'rb') as stream:
        reader = make_reader(stream)
        assert reader.get_header().profile == 'ros2'
        summary = reader.get_summary()
        assert {s.encoding for s in summary.schemas.values()} == {'ros2msg'}
        assert len(summary.schemas) == len(COUNTS)  # one schema per type
        channels = {c.topic: c for c in summary.channels.values()}
        assert set(channels) == set(COUNTS)
        for topic, channel in channels.items():
            assert channel.message_encoding == 'cdr'
            name = TF_TYPE if topic == '/tf' else type_name(TOPICS[topic][0])
            assert summary.schemas[channel.schema_id].name == name
            assert set(channel.metadata) == {'offered_qos_profiles', 'topic_type_hash'}
            assert channel.metadata['topic_type_hash'] == (
                JAZZY.hash_rihs01(TF_TYPE) if topic == '/tf' else rosidl_hash(name))
        assert summary.statistics.message_count == sum(COUNTS.values())
        assert summary.chunk_indexes
        for chunk in summary.chunk_indexes:
            assert chunk.compression == 'zstd'
            assert chunk.compressed_size < chunk.uncompressed_size
            assert chunk.message_index_offsets  # ros2 bag play's time-ordered reading needs them
        records = list(reader.iter_metadata())
    assert [r.name for r in records] == ['rosbag2']
    assert records[0].metadata['ROS_DISTRO'] == 'jazzy'
    stored = yaml.safe_load(records[0].metadata['serialized_metadata'])
    info = yaml.safe_load((path / 'metadata.yaml').read_text())['rosbag2_bagfile_information']
    assert stored == info  # every key rosbag2's BagMetadata decoder requires


@pytest.mark.parametrize('compression', ['lz4', 'none'])
def test_other_chunk_compressions_read_back(tmp_path, compression):
    """lz4 and uncompressed chunks are read by rosbags and by our reader."""
    with BagRecorder(tmp_path / 'bag', compression=compression) as recorder:
        recorder.add_topic('/robot0/odom', Odometry, RELIABLE)
        for i in range(20):
            recorder.write('/robot0/odom', odometry(i), 1000 + i)
    with open(tmp_path / 'bag' / 'bag_0.mcap', 'rb') as stream:
        chunks = make_reader(stream).get_summary().chunk_indexes
    assert {c.compression for c in chunks} == {'lz4' if compression == 'lz4' else ''}
    with AnyReader([tmp_path / 'bag']) as reader:
        decoded = [reader.deserialize(raw, c.msgtype) for c, _, raw in reader.messages()]
    assert len(decoded) == 20
    assert_same(odometry(19), decoded[-1])
    ours = [m.message for m in BagReader(tmp_path / 'bag').messages()]
    assert_same(odometry(7), ours[7])


def test_qos_metadata_is_rosbag2s_version_9_encoding(known_bag):
    """A channel's offered_qos_profiles is YAML of rosbag2's version-9 QoS: names, sec/nsec."""
    path, _ = known_bag
    with open(path / 'known_0.mcap', 'rb') as stream:
        channels = make_reader(stream).get_summary().channels.values()
    (clock,) = [c for c in channels if c.topic == '/clock']
    assert yaml.safe_load(clock.metadata['offered_qos_profiles']) == [{
        'history': 'keep_last', 'depth': 1, 'reliability': 'best_effort',
        'durability': 'volatile', 'deadline': {'sec': 9223372036, 'nsec': 854775807},
        'lifespan': {'sec': 0, 'nsec': 0}, 'liveliness': 'automatic',
        'liveliness_lease_duration': {'sec': 1, 'nsec': 500000000},
        'avoid_ros_namespace_conventions': False}]


def test_our_reader_reads_topics_qos_and_messages(known_bag):
    """bag_reader lists topics with types/counts/QoS and deserializes with rclpy."""
    path, written = known_bag
    reader = BagReader(path)
    assert {t.name: t.message_count for t in reader.topics.values()} == COUNTS
    for topic, info in reader.topics.items():
        assert len(info.qos_profiles) == 1
        assert rosbags_qos(info.qos_profiles[0]) == rosbags_qos(expected_qos(topic))
    assert reader.topics['/diagnostics'].type_name == 'diagnostic_msgs/msg/DiagnosticArray'
    rclpy_topics = [topic for topic in COUNTS if topic != '/tf']
    read = {topic: [] for topic in rclpy_topics}
    times = []
    for topic, name, t, msg in reader.messages(topics=rclpy_topics):
        assert name == type_name(type(msg))
        read[topic].append((t, msg))
        times.append(t)
    assert times == sorted(times)
    for topic in rclpy_topics:
        assert [t for t, _ in read[topic]] == [t for t, _ in written[topic]]
        for (_, original), (_, decoded) in zip(written[topic], read[topic]):
            assert_same(original, decoded, topic)
    tf_raw = [m.message for m in reader.messages(topics=['/tf'], raw=True)]
    assert tf_raw == [JAZZY.serialize_cdr(msg, TF_TYPE) for _, msg in written['/tf']]
    with pytest.raises(LookupError, match='raw=True'):
        next(reader.messages(topics=['/tf']))


def test_messages_come_in_log_time_order(tmp_path):
    """Messages written out of time order are read back sorted by log time."""
    with BagRecorder(tmp_path / 'bag') as recorder:
        recorder.add_topic('/clock', Clock, CLOCK_QOS)
        for ms in (5, 1, 4, 2, 3):
            recorder.write('/clock', clock(ms), ms)
    assert [m.log_time_ns for m in BagReader(tmp_path / 'bag').messages()] == [1, 2, 3, 4, 5]


def test_flush_puts_everything_written_so_far_on_disk(tmp_path):
    """After flush() an open bag's file already holds every message written (no footer yet)."""
    with BagRecorder(tmp_path / 'bag', flush_interval_s=3600.0) as recorder:
        recorder.add_topic('/clock', Clock, CLOCK_QOS)
        for ms in range(1, 8):
            recorder.write('/clock', clock(ms), ms)
        recorder.flush()
        snapshot = tmp_path / 'snapshot.mcap'
        snapshot.write_bytes(recorder.mcap_path.read_bytes())
        recovered = [m.log_time_ns for m in BagReader(snapshot).messages()]
    assert recovered == list(range(1, 8))


def test_finished_chunks_are_in_the_file_without_a_flush(tmp_path):
    """A chunk finished by size is in the file at once: only the open chunk is missing."""
    chunk_size = 2048
    with BagRecorder(tmp_path / 'bag', chunk_size=chunk_size,
                     flush_interval_s=3600.0) as recorder:
        recorder.add_topic('/cmd_vel', Twist, RELIABLE)
        for i in range(250):
            recorder.write('/cmd_vel', Twist(linear=Vector3(x=float(i))), 1 + i)
        snapshot = tmp_path / 'snapshot.mcap'
        snapshot.write_bytes(recorder.mcap_path.read_bytes())
    speeds = [m.message.linear.x for m in BagReader(snapshot).messages()]
    assert speeds == [float(i) for i in range(len(speeds))]
    open_chunk = 250 - len(speeds)  # each held at least its CDR bytes in the open chunk
    assert 0 < open_chunk * len(serialize_message(Twist())) <= chunk_size


def test_misuse_is_refused_and_close_is_idempotent(tmp_path):
    """Unknown topic or type, wrong type, negative time, retyped topic, bag exists; close twice."""
    recorder = BagRecorder(tmp_path / 'bag')
    recorder.add_topic('/cmd', Twist, RELIABLE)
    recorder.add_topic('/cmd', Twist, RELIABLE)  # same type again: no-op
    with pytest.raises(ValueError, match='not a ROS 2 Jazzy message type'):
        recorder.add_topic('/own', 'my_pkg/msg/Own', RELIABLE)
    with pytest.raises(ValueError, match='already recorded'):
        recorder.add_topic('/cmd', Odometry, RELIABLE)
    with pytest.raises(KeyError):
        recorder.write('/nope', Twist(), 1)
    with pytest.raises(TypeError):
        recorder.write('/cmd', Odometry(), 1)
    with pytest.raises(ValueError, match='unsigned'):
        recorder.write('/cmd', Twist(), -1)
    recorder.write('/cmd', Twist(), 1)
    recorder.close()
    recorder.close()
    recorder.write('/cmd', Twist(), 2)  # after close: discarded
    assert recorder.closed and recorder.message_counts == {'/cmd': 1}
    with pytest.raises(FileExistsError):
        BagRecorder(tmp_path / 'bag')
    with pytest.raises(ValueError, match='compression'):
        BagRecorder(tmp_path / 'other', compression='gzip')


def test_close_from_another_thread_while_threads_write(tmp_path):
    """Writers on four threads and a concurrent close leave a consistent, readable bag."""
    recorder = BagRecorder(tmp_path / 'bag', chunk_size=4096)
    for k in range(4):
        recorder.add_topic(f'/w{k}', Twist, RELIABLE)
    errors = []

    def writer(k):
        try:
            for i in range(2000):
                recorder.write(f'/w{k}', Twist(linear=Vector3(x=float(i))), 1 + i)
        except Exception as exc:  # pragma: no cover - reported below
            errors.append(exc)

    threads = [threading.Thread(target=writer, args=(k,)) for k in range(4)]
    for thread in threads:
        thread.start()
    time.sleep(0.05)
    recorder.close()
    for thread in threads:
        thread.join()
    assert not errors
    with AnyReader([tmp_path / 'bag']) as reader:
        counts = {c.topic: c.msgcount for c in reader.connections}
        read = {topic: 0 for topic in counts}
        for connection, _, _ in reader.messages():
            read[connection.topic] += 1
    assert counts == read == recorder.message_counts


@pytest.fixture
def sigusr1_previous():
    """Install a recording Python handler for SIGUSR1; restore the original afterwards."""
    calls = []
    original = signal.signal(signal.SIGUSR1, lambda signum, frame: calls.append(signum))
    yield calls
    signal.signal(signal.SIGUSR1, original)


def test_signal_closes_the_bag_then_runs_the_previous_handler(tmp_path, sigusr1_previous):
    """An idle recorder closes at once on the signal; the previous handler still runs."""
    recorder = BagRecorder(tmp_path / 'bag')
    recorder.add_topic('/cmd', Twist, RELIABLE)
    recorder.write('/cmd', Twist(), 1)
    close_on_signals(recorder, signals=(signal.SIGUSR1,))
    signal.raise_signal(signal.SIGUSR1)
    assert recorder.closed and sigusr1_previous == [signal.SIGUSR1]
    assert (tmp_path / 'bag' / 'metadata.yaml').exists()


def test_signal_during_a_write_is_handled_when_the_write_returns(tmp_path, sigusr1_previous):
    """A signal landing inside write() (lock held) closes the bag right after that write."""
    recorder = BagRecorder(tmp_path / 'bag')
    recorder.add_topic('/cmd', Twist, RELIABLE)
    close_on_signals(recorder, signals=(signal.SIGUSR1,))
    writer = recorder._writer  # white box: make the signal land mid-write, deterministically
    add_message = writer.add_message

    def add_message_then_signal(*args):
        add_message(*args)
        signal.raise_signal(signal.SIGUSR1)
        assert not recorder.closed and not sigusr1_previous  # deferred while writing

    writer.add_message = add_message_then_signal
    recorder.write('/cmd', Twist(), 5)
    assert recorder.closed and sigusr1_previous == [signal.SIGUSR1]
    with AnyReader([tmp_path / 'bag']) as reader:
        assert [t for _, t, _ in reader.messages()] == [5]


def test_signal_while_held_waits_for_the_section_end(tmp_path, sigusr1_previous):
    """Published-then-recorded inside ``holding_signals``: a signal there loses nothing.

    The signal lands before the write of the section (after the "publish"); the bag stays
    open for that write and closes as the section ends, the previous handler after it.
    """
    recorder = BagRecorder(tmp_path / 'bag')
    recorder.add_topic('/cmd', Twist, RELIABLE)
    close_on_signals(recorder, signals=(signal.SIGUSR1,))
    with recorder.holding_signals():
        signal.raise_signal(signal.SIGUSR1)
        recorder.write('/cmd', Twist(), 7)
        assert not recorder.closed and not sigusr1_previous
    assert recorder.closed and sigusr1_previous == [signal.SIGUSR1]
    with AnyReader([tmp_path / 'bag']) as reader:
        assert [t for _, t, _ in reader.messages()] == [7]


def test_ignored_signal_stays_ignored(tmp_path):
    """A signal the process ignores is not turned into a bag close."""
    original = signal.signal(signal.SIGUSR2, signal.SIG_IGN)
    try:
        with BagRecorder(tmp_path / 'bag') as recorder:
            close_on_signals(recorder, signals=(signal.SIGUSR2,))
            assert signal.getsignal(signal.SIGUSR2) is signal.SIG_IGN
    finally:
        signal.signal(signal.SIGUSR2, original)


def run_helper(bag, *args, stop_with, after_s=1.0, ready='recording'):
    """Run record_until_signal.py; send ``stop_with`` ``after_s`` after a line starts ``ready``.

    Returns the finished process with its output lines in ``stdout_lines``.
    """
    env = dict(os.environ, PYTHONPATH=os.pathsep.join(
        filter(None, [str(REPO), os.environ.get('PYTHONPATH')])), PYTHONUNBUFFERED='1')
    proc = subprocess.Popen([sys.executable, str(HELPER), str(bag), *args], cwd=REPO, env=env,
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    lines = []
    try:
        while not (lines and lines[-1].startswith(ready)):
            readable, _, _ = select.select([proc.stdout], [], [], 30.0)
            assert readable, f'no {ready!r} line from the helper'
            lines.append(proc.stdout.readline())
            assert lines[-1], proc.stderr.read()
        time.sleep(after_s)
        proc.send_signal(stop_with)
        out, err = proc.communicate(timeout=20.0)
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.wait()
    proc.stdout_lines = lines + out.splitlines(keepends=True)
    proc.stderr_text = err
    return proc


@pytest.mark.parametrize('stop_with, args, exit_code', [
    (signal.SIGINT, (), 0),
    (signal.SIGTERM, (), 128 + signal.SIGTERM),
    (signal.SIGINT, ('--rclpy',), 0),
], ids=['sigint', 'sigterm', 'sigint-rclpy-spin'])
def test_interrupted_recording_is_a_complete_bag(tmp_path, stop_with, args, exit_code):
    """SIGINT/SIGTERM mid-recording: clean exit, and rosbags opens the bag with messages."""
    proc = run_helper(tmp_path / 'bag', *args, stop_with=stop_with)
    assert proc.returncode == exit_code, proc.stderr_text
    assert 'Traceback' not in proc.stderr_text, proc.stderr_text
    with AnyReader([tmp_path / 'bag']) as reader:
        counts = {c.topic: c.msgcount for c in reader.connections}
        assert counts['/cmd_vel'] > 0 and counts['/clock'] > 0
        assert sum(1 for _ in reader.messages()) == sum(counts.values())


def test_hard_killed_recording_keeps_every_finished_chunk(tmp_path):
    """SIGKILL mid-chunk: no footer or metadata.yaml, yet every chunk finished before is read.

    Chunks end only at the helper's flushes, every 50 records, each reported once
    done; the kill comes while the next chunk is open.  What comes back is exactly
    the records up to some flush at or after the last one reported, each message
    deserialized.
    """
    every = 50
    proc = run_helper(tmp_path / 'bag', '--flush-every', str(every), stop_with=signal.SIGKILL,
                      after_s=0.02, ready='flushed')
    assert proc.returncode == -signal.SIGKILL
    assert not (tmp_path / 'bag' / 'metadata.yaml').exists()
    flushed = max(int(line.split()[1]) for line in proc.stdout_lines
                  if line.startswith('flushed'))
    reader = BagReader(tmp_path / 'bag')
    counts = {name: topic.message_count for name, topic in reader.topics.items()}
    assert counts['/cmd_vel'] == counts['/clock'] >= flushed > 0
    assert counts['/cmd_vel'] % every == 0  # whole chunks, nothing of the open one
    by_topic = {'/cmd_vel': [], '/clock': []}
    for message in reader.messages():
        by_topic[message.topic].append(message.message)
    speeds = [m.linear.x for m in by_topic['/cmd_vel']]
    assert speeds == [float(i) for i in range(counts['/cmd_vel'])]
    assert len(by_topic['/clock']) == counts['/clock']
    assert all(isinstance(m, Clock) for m in by_topic['/clock'])


finite_or_not = st.floats(width=64)
ros_text = st.text(st.characters(exclude_categories=('Cs',), exclude_characters='\x00'),
                   max_size=12)


@st.composite
def twists(draw):
    """Draw a Twist with any float64 values (NaN and infinities included)."""
    values = draw(st.lists(finite_or_not, min_size=6, max_size=6))
    return Twist(linear=Vector3(x=values[0], y=values[1], z=values[2]),
                 angular=Vector3(x=values[3], y=values[4], z=values[5]))


@st.composite
def odometries(draw):
    """Draw an Odometry with random stamp, frame names, pose, twist and covariances."""
    msg = Odometry(child_frame_id=draw(ros_text))
    msg.header = Header(stamp=Time(sec=draw(st.integers(-2 ** 31, 2 ** 31 - 1)),
                                   nanosec=draw(st.integers(0, 2 ** 32 - 1))),
                        frame_id=draw(ros_text))
    p = draw(st.lists(finite_or_not, min_size=7, max_size=7))
    msg.pose.pose = Pose(position=Point(x=p[0], y=p[1], z=p[2]),
                         orientation=Quaternion(x=p[3], y=p[4], z=p[5], w=p[6]))
    msg.pose.covariance = draw(st.lists(finite_or_not, min_size=36, max_size=36))
    msg.twist.twist = draw(twists())
    msg.twist.covariance = draw(st.lists(finite_or_not, min_size=36, max_size=36))
    return msg


@settings(max_examples=25, deadline=None)
@given(st.lists(twists(), min_size=1, max_size=4), st.lists(odometries(), min_size=1, max_size=3))
def test_random_twist_and_odometry_round_trip_exactly(twist_msgs, odom_msgs):
    """Any Twist/Odometry content comes back bit-exact through rosbags and our reader."""
    with tempfile.TemporaryDirectory() as tmp:
        bag = Path(tmp) / 'bag'
        with BagRecorder(bag) as recorder:
            recorder.add_topic('/cmd_vel', Twist, RELIABLE)
            recorder.add_topic('/odom', Odometry, RELIABLE)
            for i, msg in enumerate(twist_msgs):
                recorder.write('/cmd_vel', msg, 100 + 2 * i)
            for i, msg in enumerate(odom_msgs):
                recorder.write('/odom', msg, 101 + 2 * i)
        expected = {'/cmd_vel': twist_msgs, '/odom': odom_msgs}
        with AnyReader([bag]) as reader:
            decoded = {'/cmd_vel': [], '/odom': []}
            for connection, _, raw in reader.messages():
                decoded[connection.topic].append(reader.deserialize(raw, connection.msgtype))
        ours = {'/cmd_vel': [], '/odom': []}
        for topic, _, _, msg in BagReader(bag).messages():
            ours[topic].append(msg)
        for topic, messages in expected.items():
            assert len(decoded[topic]) == len(ours[topic]) == len(messages)
            for original, theirs, mine in zip(messages, decoded[topic], ours[topic]):
                assert_same(original, theirs, topic)
                assert_same(original, mine, topic)
