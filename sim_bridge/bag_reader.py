"""Small reader of ROS 2 MCAP bags for replay, independent of rosbag2.

``BagReader(path)`` opens a rosbag2 bag directory (its ``metadata.yaml`` names the
MCAP files; without one, every ``*.mcap`` in it, sorted) or a single ``.mcap``
file.  ``topics`` lists each topic's type, message count, offered QoS profiles
(parsed from the channel's ``offered_qos_profiles``, rosbag2 metadata version 8
or 9) and type hash; ``time_range`` gives the first and last log time;
``messages()`` yields ``(topic, type_name, log_time_ns, message)`` in log-time
order per file (ties in file order), optionally only of some topics and of a
log-time window ``start_ns <= t < end_ns``, messages deserialized with
``rclpy.serialization.deserialize_message`` into the classes ``pkg.msg.Type``, or
left as CDR bytes with ``raw=True`` (what a player publishes as it is).

A file cut short by a hard kill (no summary or footer) is read by scanning
from the start up to the last complete record, so every chunk written before
the kill is recovered.
"""
import functools
import struct
from pathlib import Path
from typing import NamedTuple

import yaml
from mcap.exceptions import McapError
from mcap.reader import SeekingReader
from mcap.records import Channel, Message, Schema
from mcap.stream_reader import StreamReader
from rclpy.duration import Duration
from rclpy.qos import (
    DurabilityPolicy,
    HistoryPolicy,
    LivelinessPolicy,
    QoSProfile,
    ReliabilityPolicy,
)
from rclpy.serialization import deserialize_message

from sim_bridge.msg_definitions import message_class


class BagTopic(NamedTuple):
    """One recorded topic."""

    name: str
    type_name: str
    message_count: int
    qos_profiles: tuple
    type_hash: str


class BagMessage(NamedTuple):
    """One recorded message; ``message`` is the CDR bytes when read with ``raw=True``."""

    topic: str
    type_name: str
    log_time_ns: int
    message: object


def parse_qos_profiles(text):
    """Return the ``QoSProfile`` list of an ``offered_qos_profiles`` YAML string."""
    return [_qos_profile(item) for item in yaml.safe_load(text or '[]') or []]


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
    def topics(self):
        """Return ``{topic: BagTopic}`` over all files of the bag."""
        found = {}
        for path in self.files:
            for channel, schema, count in _file_channels(path):
                known = found.get(channel.topic)
                if known is not None:
                    found[channel.topic] = known._replace(
                        message_count=known.message_count + count)
                    continue
                found[channel.topic] = BagTopic(
                    channel.topic, schema.name if schema else '', count,
                    tuple(parse_qos_profiles(channel.metadata.get('offered_qos_profiles', ''))),
                    channel.metadata.get('topic_type_hash', ''))
        return found

    @functools.cached_property
    def time_range(self):
        """Return ``(first, last)`` log time [ns] over all files; ``(None, None)`` if empty."""
        first = last = None
        for path in self.files:
            for start, end in _file_time_range(path):
                first = start if first is None else min(first, start)
                last = end if last is None else max(last, end)
        return first, last

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


def _qos_profile(item):
    def policy(enum, value):
        return enum(value) if isinstance(value, int) else enum[value.upper()]

    def duration(value):
        return Duration(seconds=value['sec'], nanoseconds=value['nsec'])

    return QoSProfile(
        history=policy(HistoryPolicy, item['history']),
        depth=item['depth'],
        reliability=policy(ReliabilityPolicy, item['reliability']),
        durability=policy(DurabilityPolicy, item['durability']),
        deadline=duration(item['deadline']),
        lifespan=duration(item['lifespan']),
        liveliness=policy(LivelinessPolicy, item['liveliness']),
        liveliness_lease_duration=duration(item['liveliness_lease_duration']),
        avoid_ros_namespace_conventions=item['avoid_ros_namespace_conventions'])


def _summary(stream):
    """Return the file's summary, or None when it has none (cut short, or written without)."""
    try:
        return SeekingReader(stream).get_summary()
    except Exception:  # whatever the cut-off tail decodes to, there is no summary to use
        return None


def _file_channels(path):
    """Yield ``(channel, schema, message_count)`` for each channel of one MCAP file."""
    with open(path, 'rb') as stream:
        summary = _summary(stream)
        if summary is not None and summary.statistics is not None:
            counts = summary.statistics.channel_message_counts
            for channel in summary.channels.values():
                yield (channel, summary.schemas.get(channel.schema_id),
                       counts.get(channel.id, 0))
            return
        schemas, channels, counts = {}, {}, {}
        for record in _scan(stream):
            if isinstance(record, Schema):
                schemas[record.id] = record
            elif isinstance(record, Channel):
                channels[record.id] = record
            elif isinstance(record, Message):
                counts[record.channel_id] = counts.get(record.channel_id, 0) + 1
        for channel in channels.values():
            yield channel, schemas.get(channel.schema_id), counts.get(channel.id, 0)


def _file_time_range(path):
    """Yield the ``(first, last)`` log time of one MCAP file, if it has messages."""
    with open(path, 'rb') as stream:
        summary = _summary(stream)
        if summary is not None and summary.statistics is not None:
            if summary.statistics.message_count:
                yield summary.statistics.message_start_time, summary.statistics.message_end_time
            return
        times = [r.log_time for r in _scan(stream) if isinstance(r, Message)]
        if times:
            yield min(times), max(times)


def _file_messages(path, topics, start_ns=None, end_ns=None):
    """Yield ``(schema, channel, message)`` of one MCAP file, recovering a cut-short one."""
    with open(path, 'rb') as stream:
        if _summary(stream) is not None:
            stream.seek(0)
            yield from SeekingReader(stream).iter_messages(
                topics=topics, log_time_order=True, starting_at=start_ns, ending_before=end_ns)
            return
        schemas, channels = {}, {}
        for record in _scan(stream):
            if isinstance(record, Schema):
                schemas[record.id] = record
            elif isinstance(record, Channel):
                channels[record.id] = record
            elif isinstance(record, Message):
                channel = channels[record.channel_id]
                if ((topics is None or channel.topic in topics)
                        and (start_ns is None or record.log_time >= start_ns)
                        and (end_ns is None or record.log_time < end_ns)):
                    yield schemas.get(channel.schema_id), channel, record


def _scan(stream):
    """Yield the records of an MCAP stream from its start up to the first incomplete one."""
    stream.seek(0)
    records = StreamReader(stream).records
    while True:
        try:
            record = next(records)
        except (StopIteration, McapError, EOFError, OSError, ValueError, struct.error):
            return
        yield record
