"""MCAP bag recorder that writes what ``ros2 bag record -s mcap`` (Jazzy) writes.

Layout (a rosbag2 bag directory, as ``ros2 bag record -o DIR`` makes)::

    DIR/DIR_0.mcap      the data: one self-contained MCAP file
    DIR/metadata.yaml   rosbag2 metadata, version 9, written by close()

``ros2 bag info|play DIR`` and ``rosbags`` open the directory; both (and Foxglove)
also open ``DIR_0.mcap`` on its own.  The MCAP file carries what the rosbag2 MCAP
storage plugin writes (rosbag2_storage_mcap/src/mcap_storage.cpp): profile ``ros2``;
per type a schema named ``pkg/msg/Type`` with encoding ``ros2msg`` and the full
``.msg`` text (see ``msg_definitions``); per topic a channel with message encoding
``cdr`` and metadata ``offered_qos_profiles`` (the QoS YAML of rosbag2_storage's
``serialize_rclcpp_qos_vector``, version 9: enum names, durations as sec/nsec)
and ``topic_type_hash`` (RIHS01 hash, empty when the type is not installed);
messages in zstd (default) or lz4 compressed chunks with message indexes; and, on
close, a metadata record ``rosbag2`` holding the bag's metadata YAML
(``serialized_metadata``) and ``ROS_DISTRO``, which rosbag2 reads back from a
lone ``.mcap``.

Writing a message costs one CDR serialization plus an append to the open chunk;
all YAML and schema work happens in ``add_topic`` and ``close``.  A node that
publishes what it records serializes once: ``data = serialize_message(msg)``,
``publisher.publish(data)`` (rclpy publishes bytes as they are) and
``recorder.write_serialized(topic, data, t)``.  A chunk is
written out when it reaches ``chunk_size`` or is ``flush_interval_s`` old, so a
process killed hard (SIGKILL, power loss aside) loses at most the open chunk:
the file then lacks its summary and footer, which ``bag_reader`` and the MCAP
tools' recovery scan tolerate.  ``close_on_signals`` makes SIGINT/SIGTERM close
the bag cleanly before the process goes on as it would have.
"""
import functools
import json
import os
import re
import signal
import threading
import time
from pathlib import Path

from mcap.writer import CompressionType, LIBRARY_IDENTIFIER, Writer
from rclpy.serialization import serialize_message

from sim_bridge import msg_definitions

METADATA_VERSION = 9
COMPRESSION = {'zstd': CompressionType.ZSTD, 'lz4': CompressionType.LZ4,
               'none': CompressionType.NONE, None: CompressionType.NONE}
_PLAIN_SCALAR = re.compile(r'[A-Za-z0-9_/][A-Za-z0-9_./-]*')
_YAML_WORDS = {'true', 'false', 'yes', 'no', 'on', 'off', 'y', 'n', 'null', '~'}


def qos_dict(profile):
    """Return one QoS profile as rosbag2 (metadata version 9) serializes it."""
    def duration(value):
        sec, nsec = divmod(value.nanoseconds, 10 ** 9)
        return {'sec': sec, 'nsec': nsec}

    return {
        'history': profile.history.name.lower(),
        'depth': profile.depth,
        'reliability': profile.reliability.name.lower(),
        'durability': profile.durability.name.lower(),
        'deadline': duration(profile.deadline),
        'lifespan': duration(profile.lifespan),
        'liveliness': profile.liveliness.name.lower(),
        'liveliness_lease_duration': duration(profile.liveliness_lease_duration),
        'avoid_ros_namespace_conventions': profile.avoid_ros_namespace_conventions,
    }


def to_yaml(value):
    """Return a dict/list tree as block YAML laid out the way yaml-cpp emits it."""
    return '\n'.join(_yaml_lines(value, 0))


def _yaml_lines(value, indent):
    pad = ' ' * indent
    if isinstance(value, dict):
        for key, item in value.items():
            if isinstance(item, (dict, list)) and item:
                yield f'{pad}{key}:'
                yield from _yaml_lines(item, indent + 2)
            else:
                yield f'{pad}{key}: {_yaml_scalar(item)}'
        return
    for item in value:
        if isinstance(item, (dict, list)) and item:
            lines = list(_yaml_lines(item, indent + 2))
            yield f'{pad}- {lines[0].lstrip()}'
            yield from lines[1:]
        else:
            yield f'{pad}- {_yaml_scalar(item)}'


def _yaml_scalar(value):
    if value is None:
        return '~'
    if isinstance(value, bool):
        return 'true' if value else 'false'
    if isinstance(value, (dict, list)):
        return '{}' if isinstance(value, dict) else '[]'
    if isinstance(value, int):
        return str(value)
    if _PLAIN_SCALAR.fullmatch(value) and value.lower() not in _YAML_WORDS:
        try:
            float(value)
        except ValueError:
            return value
    return json.dumps(value)


class _ThreadState(threading.local):
    busy = False       # this thread is inside a locked recorder method
    deferred = None    # (previous handler, signum, frame) of a signal that arrived meanwhile


class _Topic:
    __slots__ = ('channel_id', 'msg_class', 'type_name', 'qos', 'type_hash', 'count')

    def __init__(self, channel_id, msg_class, type_name, qos, type_hash):
        self.channel_id = channel_id
        self.msg_class = msg_class
        self.type_name = type_name
        self.qos = qos
        self.type_hash = type_hash
        self.count = 0


class BagRecorder:
    """Record ROS 2 messages of any set of topics into one rosbag2 MCAP bag directory."""

    def __init__(self, path, compression='zstd', chunk_size=1 << 20, flush_interval_s=1.0):
        """Create the bag directory ``path`` and start ``<path>/<name>_0.mcap``.

        ``compression`` is ``'zstd'``, ``'lz4'`` or ``'none'``; a chunk is written
        once it holds ``chunk_size`` bytes or is ``flush_interval_s`` seconds old.
        Raises ``FileExistsError`` if the directory already holds this bag.
        """
        if compression not in COMPRESSION:
            raise ValueError(f'compression must be one of zstd, lz4, none, not {compression!r}')
        self.path = Path(path)
        self.mcap_path = self.path / f'{self.path.name}_0.mcap'
        self.metadata_path = self.path / 'metadata.yaml'
        if self.metadata_path.exists():
            raise FileExistsError(f'{self.metadata_path} exists: not overwriting a bag')
        self.path.mkdir(parents=True, exist_ok=True)
        self._file = open(self.mcap_path, 'xb')
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

    def add_topic(self, topic, msg_type, qos, definition=None):
        """Register ``topic`` with its message type and the QoS it is offered with.

        ``msg_type`` is a message class or ``'pkg/msg/Type'``; ``qos`` a
        ``QoSProfile`` or a list of them (one per publisher).  ``definition`` is the
        type's own ``.msg`` text, needed only when its package is not installed
        (then only ``write_serialized`` works on the topic).  Registering a topic
        again with the same type does nothing.
        """
        name = msg_definitions.type_name(msg_type)
        profiles = list(qos) if isinstance(qos, (list, tuple)) else [qos]
        schema = msg_definitions.full_definition(name, definition)
        msg_class = msg_type if not isinstance(msg_type, str) else _class_or_none(name)
        try:
            type_hash = msg_definitions.type_hash(name)
        except msg_definitions.DefinitionNotFoundError:
            type_hash = ''
        metadata = {'offered_qos_profiles': to_yaml([qos_dict(p) for p in profiles]),
                    'topic_type_hash': type_hash}
        with self._locked():
            known = self._topics.get(topic)
            if known is not None:
                if known.type_name != name:
                    raise ValueError(f'topic {topic} already recorded as {known.type_name}')
                return
            if self._writer is None:
                raise ValueError('recorder is closed')
            if name not in self._schema_ids:
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
                writer.add_metadata('rosbag2', {'serialized_metadata': to_yaml(info),
                                                'ROS_DISTRO': info['ros_distro']})
                writer.finish()
            finally:
                self._file.close()
            tmp = self.metadata_path.with_name('metadata.yaml.tmp')
            tmp.write_text(to_yaml({'rosbag2_bagfile_information': info}) + '\n')
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
        state.busy = True
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
            state.busy = False
            if state.deferred is not None:
                self._handle_deferred_signal()

    def _locked(self):
        return _LockedSection(self)

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
                'offered_qos_profiles': [qos_dict(p) for p in topic.qos],
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
    """Hold the recorder lock, marking the thread busy so a signal waits for the exit."""

    __slots__ = ('recorder',)

    def __init__(self, recorder):
        self.recorder = recorder

    def __enter__(self):
        self.recorder._state.busy = True
        self.recorder._lock.acquire()

    def __exit__(self, *exc_info):
        recorder = self.recorder
        recorder._lock.release()
        recorder._state.busy = False
        if recorder._state.deferred is not None:
            recorder._handle_deferred_signal()


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
    if state.busy:
        state.deferred = (previous, signum, frame)
        return
    recorder.close()
    _continue_signal(previous, signum, frame)


def _continue_signal(previous, signum, frame):
    if callable(previous):
        previous(signum, frame)
    else:
        raise SystemExit(128 + signum)


def _class_or_none(name):
    try:
        return msg_definitions.message_class(name)
    except msg_definitions.DefinitionNotFoundError:
        return None
