"""Reader of ROS 2 MCAP bags for replay, on the ``mcap`` library and rclpy.

``BagReader(path)`` opens a rosbag2 bag directory (its ``metadata.yaml`` names the
MCAP files; without one, every ``*.mcap`` in it, sorted) or a single ``.mcap``
file.  ``topics`` lists each topic's type, message count and offered QoS
profiles (the channel's ``offered_qos_profiles``, rosbag2 metadata version 8
or 9, parsed by rosbags' ``parse_qos``); ``time_range`` gives the first and
last log time; ``messages()`` yields ``(topic, type_name, log_time_ns,
message)`` in log-time order per file (ties in file order), optionally only of
some topics and of a log-time window ``start_ns <= t < end_ns``, messages
deserialized with ``rclpy.serialization.deserialize_message`` into the classes
``pkg.msg.Type`` (``message_class``), or left as CDR bytes with ``raw=True``
(what a player publishes as it is).

A file cut short by a hard kill (no footer, so no summary: rosbags' reader
refuses it) is read in file order by the mcap library's non-seeking reader up
to its first incomplete record, so every chunk finished before the kill is
recovered; its ``topics`` are those with recovered messages.
"""
import functools
import importlib
import io
from pathlib import Path
from typing import NamedTuple

import yaml
from mcap.exceptions import McapError
from mcap.reader import NonSeekingReader, SeekingReader
from mcap.writer import MCAP0_MAGIC
from rclpy.duration import Duration
from rclpy.qos import (
    DurabilityPolicy,
    HistoryPolicy,
    LivelinessPolicy,
    QoSProfile,
    ReliabilityPolicy,
)
from rclpy.serialization import deserialize_message
from rosbags.rosbag2.metadata import parse_qos


class BagTopic(NamedTuple):
    """One recorded topic."""

    name: str
    type_name: str
    message_count: int
    qos_profiles: tuple


class BagMessage(NamedTuple):
    """One recorded message; ``message`` is the CDR bytes when read with ``raw=True``."""

    topic: str
    type_name: str
    log_time_ns: int
    message: object


@functools.lru_cache(maxsize=None)
def message_class(type_name):
    """Return the rclpy class of ``'pkg/msg/Type'``; ``LookupError`` if it is not installed."""
    package, _, short = type_name.partition('/msg/')
    if not (package and short) or '/' in package + short:
        raise ValueError(f'not a message type name: {type_name!r} (expected pkg/msg/Type)')
    try:
        return getattr(importlib.import_module(f'{package}.msg'), short)
    except (ImportError, AttributeError):
        raise LookupError(f'message class {package}.msg.{short} is not installed') from None


class BagReader:
    """Read the topics and messages of an MCAP bag (directory or file)."""

    def __init__(self, path):
        """Find the MCAP files of the bag at ``path``."""
        path = Path(path)
        if path.is_file():
            self.files = [path]
        elif (path / 'metadata.yaml').is_file():
            info = yaml.safe_load((path / 'metadata.yaml').read_text())
            names = info['rosbag2_bagfile_information']['relative_file_paths']
            self.files = [path / Path(name).name for name in names]
        else:
            self.files = sorted(path.glob('*.mcap'))
        if not self.files:
            raise FileNotFoundError(f'no MCAP file in {path}')

    @functools.cached_property
    def _overviews(self):
        return [_overview(path) for path in self.files]

    @functools.cached_property
    def topics(self):
        """Return ``{topic: BagTopic}`` over all files of the bag."""
        found = {}
        for channels, _, _ in self._overviews:
            for channel, schema, count in channels:
                known = found.get(channel.topic)
                if known is not None:
                    found[channel.topic] = known._replace(
                        message_count=known.message_count + count)
                    continue
                profiles = parse_qos(channel.metadata.get('offered_qos_profiles', ''))
                found[channel.topic] = BagTopic(
                    channel.topic, schema.name if schema else '', count,
                    tuple(_rclpy_qos(qos) for qos in profiles))
        return found

    @functools.cached_property
    def time_range(self):
        """Return ``(first, last)`` log time [ns] over all files; ``(None, None)`` if empty."""
        starts = [first for _, first, _ in self._overviews if first is not None]
        ends = [last for _, _, last in self._overviews if last is not None]
        return (min(starts), max(ends)) if starts else (None, None)

    def messages(self, topics=None, raw=False, start_ns=None, end_ns=None):
        """Yield ``BagMessage`` tuples, only of ``topics`` if given; CDR bytes if ``raw``.

        ``start_ns`` / ``end_ns`` keep the log times ``start_ns <= t < end_ns``.
        """
        wanted = None if topics is None else set(topics)
        for path in self.files:
            for schema, channel, record in _file_messages(path, wanted, start_ns, end_ns):
                type_name = schema.name if schema else ''
                if raw:
                    message = record.data
                else:
                    try:
                        cls = message_class(type_name)
                    except (LookupError, ValueError) as exc:
                        raise LookupError(f'cannot deserialize {channel.topic}: {exc}; '
                                          'read it with raw=True') from None
                    message = deserialize_message(record.data, cls)
                yield BagMessage(channel.topic, type_name, record.log_time, message)


def _rclpy_qos(qos):
    """Return rosbags' ``Qos`` as an rclpy ``QoSProfile`` (their policy enums share values)."""
    def duration(value):
        return Duration(seconds=value.sec, nanoseconds=value.nsec)

    return QoSProfile(
        history=HistoryPolicy(qos.history.value), depth=qos.depth,
        reliability=ReliabilityPolicy(qos.reliability.value),
        durability=DurabilityPolicy(qos.durability.value),
        deadline=duration(qos.deadline), lifespan=duration(qos.lifespan),
        liveliness=LivelinessPolicy(qos.liveliness.value),
        liveliness_lease_duration=duration(qos.liveliness_lease_duration),
        avoid_ros_namespace_conventions=qos.avoid_ros_namespace_conventions)


def _indexed_reader(stream):
    """Return a ``SeekingReader`` of a finished file with a summary, else None.

    A finished file ends in the MCAP magic after its footer; one cut short does not.
    """
    end = stream.seek(0, io.SEEK_END)
    stream.seek(max(0, end - len(MCAP0_MAGIC)))
    if end <= len(MCAP0_MAGIC) or stream.read() != MCAP0_MAGIC:
        return None
    stream.seek(0)
    reader = SeekingReader(stream)
    summary = reader.get_summary()
    return reader if summary is not None and summary.statistics is not None else None


def _overview(path):
    """Return ``([(channel, schema, message count)], first, last)`` of one MCAP file."""
    with open(path, 'rb') as stream:
        reader = _indexed_reader(stream)
        summary = reader and reader.get_summary()
    if summary is not None:
        stats = summary.statistics
        channels = [(channel, summary.schemas.get(channel.schema_id),
                     stats.channel_message_counts.get(channel.id, 0))
                    for channel in summary.channels.values()]
        if not stats.message_count:
            return channels, None, None
        return channels, stats.message_start_time, stats.message_end_time
    found, counts, first, last = {}, {}, None, None
    for schema, channel, record in _file_messages(path):
        found[channel.id] = (channel, schema)
        counts[channel.id] = counts.get(channel.id, 0) + 1
        first = record.log_time if first is None else min(first, record.log_time)
        last = record.log_time if last is None else max(last, record.log_time)
    channels = [(channel, schema, counts[key]) for key, (channel, schema) in found.items()]
    return channels, first, last


def _file_messages(path, topics=None, start_ns=None, end_ns=None):
    """Yield ``(schema, channel, message)`` of one MCAP file, recovering a cut-short one."""
    with open(path, 'rb') as stream:
        window = dict(starting_at=start_ns, ending_before=end_ns)
        reader = _indexed_reader(stream)
        if reader is not None:
            yield from reader.iter_messages(topics, log_time_order=True, **window)
            return
        stream.seek(0)
        try:
            yield from NonSeekingReader(stream).iter_messages(topics, log_time_order=False,
                                                              **window)
        except McapError:  # the first incomplete record (EndOfFile): the end of what is kept
            return
