"""MCAP bag recorder that writes what ``ros2 bag record -s mcap`` (Jazzy) writes.

Layout (a rosbag2 bag directory, as ``ros2 bag record -o DIR`` makes)::

    DIR/DIR_0.mcap      the data: one self-contained MCAP file
    DIR/metadata.yaml   rosbag2 metadata, version 9, written by close()

``ros2 bag info|play DIR`` and ``rosbags`` open the directory; both (and Foxglove)
also open ``DIR_0.mcap`` on its own.  The file is written by the ``mcap``
library's ``Writer`` with what the rosbag2 MCAP storage plugin writes: profile
``ros2``; per type a schema ``pkg/msg/Type``, encoding ``ros2msg``, text from
rosbags' Jazzy type store (``generate_msgdef``: the type's fields, then each
dependency after a line of 80 ``=`` and ``MSG: pkg/Type``); per topic a
channel with message encoding ``cdr`` and metadata ``offered_qos_profiles``
(rosbags' ``dump_qos_v9`` as YAML) and ``topic_type_hash`` (the type store's
RIHS01 hash, which rclpy reports too); messages in zstd (default) or lz4
compressed chunks with message indexes; and, on close, a metadata record
``rosbag2`` holding the bag's metadata YAML (``serialized_metadata``) and
``ROS_DISTRO``, which rosbag2 reads back from a lone ``.mcap``.  YAML is
PyYAML's.

Writing a message costs one CDR serialization plus an append to the open
chunk.  A node that publishes what it records serializes once: ``data =
serialize_message(msg)``, ``publisher.publish(data)`` and
``recorder.write_serialized(topic, data, t)``.  A chunk is finished once it
holds ``chunk_size`` bytes, or by the first write more than
``flush_interval_s`` after the last one was, and reaches the OS at once, so a
process killed hard (SIGKILL; power loss aside) loses only the open chunk: the
file then lacks its summary and footer, which ``bag_reader`` (and the MCAP
tools' recovery) read past; bench/bench_bag_kill.py measures what is kept.
rosbags' own rosbag2 ``Writer`` is not used: it finishes a chunk only at 1 MiB
(uncompressed) and names the file ``DIR.mcap``.  ``close_on_signals`` makes
SIGINT/SIGTERM close the bag cleanly before the process goes on as it would
have.
"""
import dataclasses
import functools
import io
import os
import signal
import threading
import time
from pathlib import Path

import yaml
from mcap.writer import CompressionType, LIBRARY_IDENTIFIER, Writer
from rclpy.serialization import serialize_message
from rosbags import interfaces
from rosbags.rosbag2.metadata import dump_qos_v9
from rosbags.typesys import get_typestore, Stores

METADATA_VERSION = 9
COMPRESSION = {'zstd': CompressionType.ZSTD, 'lz4': CompressionType.LZ4,
               'none': CompressionType.NONE}
TYPESTORE = get_typestore(Stores.ROS2_JAZZY)


def _rosbags_qos(profile):
    """Return an rclpy ``QoSProfile`` as rosbags' ``Qos`` (their policy enums share values)."""
    def qos_time(duration):
        return interfaces.QosTime(*divmod(duration.nanoseconds, 10 ** 9))

    return interfaces.Qos(
        interfaces.QosHistory(profile.history.value), profile.depth,
        interfaces.QosReliability(profile.reliability.value),
        interfaces.QosDurability(profile.durability.value), qos_time(profile.deadline),
        qos_time(profile.lifespan), interfaces.QosLiveliness(profile.liveliness.value),
        qos_time(profile.liveliness_lease_duration), profile.avoid_ros_namespace_conventions)


def _yaml(value):
    """Return ``value`` as block YAML, keys in insertion order."""
    return yaml.safe_dump(value, default_flow_style=False, sort_keys=False)


def _type_name(msg_type):
    """Return ``'pkg/msg/Type'`` of a message class (a string is returned as it is)."""
    if isinstance(msg_type, str):
        return msg_type
    return f'{msg_type.__module__.split(".")[0]}/msg/{msg_type.__name__}'


class _ThreadState(threading.local):
    depth = 0          # recorder sections (locked methods, held signals) this thread is in
    deferred = None    # (previous handler, signum, frame) of a signal that arrived meanwhile


@dataclasses.dataclass(slots=True)
class _Topic:
    channel_id: int
    msg_class: type
    type_name: str
    qos: list
    type_hash: str
    count: int = 0


class BagRecorder:
    """Record ROS 2 messages of any set of topics into one rosbag2 MCAP bag directory."""

    def __init__(self, path, compression='zstd', chunk_size=1 << 20, flush_interval_s=1.0):
        """Create the bag directory ``path`` and start ``<path>/<name>_0.mcap``.

        ``compression`` is ``'zstd'``, ``'lz4'`` or ``'none'``; a chunk is finished
        once it holds ``chunk_size`` bytes, or by the first write more than
        ``flush_interval_s`` seconds after the last one was.  Raises
        ``FileExistsError`` if the directory already holds this bag.
        """
        if compression not in COMPRESSION:
            raise ValueError(f'compression must be one of zstd, lz4, none, not {compression!r}')
        self.path = Path(path)
        self.mcap_path = self.path / f'{self.path.name}_0.mcap'
        self.metadata_path = self.path / 'metadata.yaml'
        if self.metadata_path.exists():
            raise FileExistsError(f'{self.metadata_path} exists: not overwriting a bag')
        self.path.mkdir(parents=True, exist_ok=True)
        # A 1-byte buffer: each batch of records the writer emits (a finished chunk, its
        # message indexes) reaches the OS at once, so a SIGKILL cannot keep it back.
        self._file = io.BufferedWriter(io.FileIO(self.mcap_path, 'x'), buffer_size=1)
        self._writer = Writer(self._file, chunk_size=chunk_size,
                              compression=COMPRESSION[compression])
        self._writer.start(profile='ros2', library=f'polyc2bf_ros {LIBRARY_IDENTIFIER}')
        self._lock = threading.Lock()
        self._state = _ThreadState()
        self._topics = {}
        self._schema_ids = {}
        self._flush_interval_s = flush_interval_s
        self._last_flush = time.monotonic()
        self._start_ns = None
        self._end_ns = None

    @property
    def closed(self):
        """Whether ``close()`` has run (later writes are discarded)."""
        return self._writer is None

    @property
    def message_counts(self):
        """Return the number of messages written so far per topic."""
        return {name: topic.count for name, topic in self._topics.items()}

    def add_topic(self, topic, msg_type, qos):
        """Register ``topic`` with its message type and the QoS it is offered with.

        ``msg_type`` is an rclpy message class or ``'pkg/msg/Type'`` (then only
        ``write_serialized`` works on the topic), a type of rosbags' Jazzy type
        store; ``qos`` a ``QoSProfile`` or a list of them (one per publisher).
        Registering a topic again with the same type does nothing.
        """
        name = _type_name(msg_type)
        if name not in TYPESTORE.types:
            raise ValueError(f'{name} is not a ROS 2 Jazzy message type known to rosbags')
        profiles = dump_qos_v9([_rosbags_qos(p) for p in
                                (qos if isinstance(qos, (list, tuple)) else [qos])])
        msg_class = None if isinstance(msg_type, str) else msg_type
        type_hash = TYPESTORE.hash_rihs01(name)
        metadata = {'offered_qos_profiles': _yaml(profiles), 'topic_type_hash': type_hash}
        with self._locked():
            known = self._topics.get(topic)
            if known is not None:
                if known.type_name != name:
                    raise ValueError(f'topic {topic} already recorded as {known.type_name}')
                return
            if self._writer is None:
                raise ValueError('recorder is closed')
            if name not in self._schema_ids:
                schema, _ = TYPESTORE.generate_msgdef(name, ros_version=2)
                self._schema_ids[name] = self._writer.register_schema(
                    name, 'ros2msg', schema.encode())
            channel_id = self._writer.register_channel(
                topic, 'cdr', self._schema_ids[name], metadata)
            self._topics[topic] = _Topic(channel_id, msg_class, name, profiles, type_hash)

    def write(self, topic, msg, log_time_ns, publish_time_ns=None):
        """Serialize ``msg`` to CDR and record it on ``topic`` at ``log_time_ns``."""
        entry = self._topic(topic)
        if type(msg) is not entry.msg_class:
            raise TypeError(f'{topic} records {entry.type_name}, not {type(msg).__name__}')
        if self._writer is not None:
            self._append(entry, serialize_message(msg), log_time_ns, publish_time_ns)

    def write_serialized(self, topic, data, log_time_ns, publish_time_ns=None):
        """Record CDR bytes ``data`` (e.g. from ``serialize_message``) on ``topic``."""
        self._append(self._topic(topic), data, log_time_ns, publish_time_ns)

    def flush(self):
        """Write out the open chunk and flush the file (a hard kill keeps what is flushed)."""
        with self._locked():
            if self._writer is not None:
                self._writer.flush()
                self._last_flush = time.monotonic()

    def close(self):
        """Finish the MCAP file (summary, footer) and write ``metadata.yaml``; idempotent."""
        with self._locked():
            writer, self._writer = self._writer, None
            if writer is None:
                return
            try:
                info = self._bag_info()
                writer.add_metadata('rosbag2', {'serialized_metadata': _yaml(info),
                                                'ROS_DISTRO': info['ros_distro']})
                writer.finish()
            finally:
                self._file.close()
            tmp = self.metadata_path.with_name('metadata.yaml.tmp')
            tmp.write_text(_yaml({'rosbag2_bagfile_information': info}))
            os.replace(tmp, self.metadata_path)

    def __enter__(self):
        """Return the recorder."""
        return self

    def __exit__(self, *exc_info):
        """Close the bag."""
        self.close()

    def _topic(self, topic):
        try:
            return self._topics[topic]
        except KeyError:
            raise KeyError(f'topic {topic} was not added to the recorder') from None

    def _append(self, entry, data, log_time_ns, publish_time_ns):
        log_time_ns = int(log_time_ns)
        publish_time_ns = log_time_ns if publish_time_ns is None else int(publish_time_ns)
        if not (0 <= log_time_ns < 1 << 64 and 0 <= publish_time_ns < 1 << 64):
            raise ValueError('MCAP times are unsigned 64-bit nanoseconds')
        state = self._state
        state.depth += 1
        try:
            with self._lock:
                writer = self._writer
                if writer is None:
                    return
                writer.add_message(entry.channel_id, log_time_ns, data, publish_time_ns)
                entry.count += 1
                if self._start_ns is None or log_time_ns < self._start_ns:
                    self._start_ns = log_time_ns
                if self._end_ns is None or log_time_ns > self._end_ns:
                    self._end_ns = log_time_ns
                now = time.monotonic()
                if now - self._last_flush > self._flush_interval_s:
                    writer.flush()
                    self._last_flush = now
        finally:
            self._leave()

    def _locked(self):
        return _LockedSection(self, locked=True)

    def holding_signals(self):
        """Return a context in which SIGINT/SIGTERM (``close_on_signals``) wait for its end.

        For a caller whose messages go out before they are recorded: publishing, then
        recording, inside one such section, a signal cannot close the bag between the two,
        so every message that went out is in the bag.
        """
        return _LockedSection(self, locked=False)

    def _leave(self):
        state = self._state
        state.depth -= 1
        if state.depth == 0 and state.deferred is not None:
            self._handle_deferred_signal()

    def _handle_deferred_signal(self):
        state = self._state
        previous, signum, frame = state.deferred
        state.deferred = None
        self.close()
        _continue_signal(previous, signum, frame)

    def _bag_info(self):
        start = self._start_ns or 0
        duration = 0 if self._end_ns is None else self._end_ns - start
        total = sum(topic.count for topic in self._topics.values())
        topics = [{
            'topic_metadata': {
                'name': name,
                'type': topic.type_name,
                'serialization_format': 'cdr',
                'offered_qos_profiles': topic.qos,
                'type_description_hash': topic.type_hash,
            },
            'message_count': topic.count,
        } for name, topic in self._topics.items()]
        file_name = self.mcap_path.name
        return {
            'version': METADATA_VERSION,
            'storage_identifier': 'mcap',
            'duration': {'nanoseconds': duration},
            'starting_time': {'nanoseconds_since_epoch': start},
            'message_count': total,
            'topics_with_message_count': topics,
            'compression_format': '',
            'compression_mode': '',
            'relative_file_paths': [file_name],
            'files': [{'path': file_name,
                       'starting_time': {'nanoseconds_since_epoch': start},
                       'duration': {'nanoseconds': duration},
                       'message_count': total}],
            'custom_data': None,
            'ros_distro': os.environ.get('ROS_DISTRO') or 'jazzy',
        }


class _LockedSection:
    """Mark the thread busy (and hold the lock if ``locked``): a signal waits for the exit."""

    __slots__ = ('recorder', 'locked')

    def __init__(self, recorder, locked):
        self.recorder = recorder
        self.locked = locked

    def __enter__(self):
        self.recorder._state.depth += 1
        if self.locked:
            self.recorder._lock.acquire()

    def __exit__(self, *exc_info):
        if self.locked:
            self.recorder._lock.release()
        self.recorder._leave()


def close_on_signals(recorder, signals=(signal.SIGINT, signal.SIGTERM)):
    """Make ``signals`` close ``recorder`` cleanly, then act as the previous handler did.

    Call from the main thread, before ``rclpy.init()`` (rclpy's handlers then chain
    to these).  After closing: a Python handler (e.g. the KeyboardInterrupt of
    SIGINT) is called; the default action becomes ``SystemExit(128 + signum)``, so
    ``finally`` blocks still run; an ignored signal stays ignored.  A signal that
    lands while the main thread is writing is handled as that write returns.
    """
    for signum in signals:
        previous = signal.getsignal(signum)
        if previous is signal.SIG_IGN:
            continue
        signal.signal(signum, functools.partial(_on_signal, recorder, previous))


def _on_signal(recorder, previous, signum, frame):
    state = recorder._state
    if state.depth:
        state.deferred = (previous, signum, frame)
        return
    recorder.close()
    _continue_signal(previous, signum, frame)


def _continue_signal(previous, signum, frame):
    if callable(previous):
        previous(signum, frame)
    else:
        raise SystemExit(128 + signum)
