"""ROS 2 message definitions and type hashes for MCAP ``ros2msg`` schemas.

``full_definition('nav_msgs/msg/Odometry')`` returns the schema text the
rosbag2 MCAP storage plugin (``rosbag2_storage_mcap``, message_definition_cache.cpp)
writes: the type's own installed ``.msg`` file, verbatim, followed, for every
dependency, by a newline, a line of 80 ``=``, a line ``MSG: pkg/Type`` and that
type's ``.msg`` text.  Dependencies are the non-primitive field types found at
the start of each line, named as the ``.msg`` file writes them (``pkg/Type``, or
the own package for a bare ``Type``), visited depth first in sorted order, each
once.

``.msg`` files are looked up in ``<share>/<pkg>/msg/``, the share directory coming
from the ament index when ``AMENT_PREFIX_PATH`` is set and ``<sys.prefix>/share``
otherwise (where the PyPI ROS wheels install them).  ``type_hash`` reads the
RIHS01 hash rosidl generated next to the ``.msg`` (``<Type>.json``), the value
rclpy/rclcpp report and rosbag2 stores as ``topic_type_hash``.
"""
import functools
import importlib
import json
import re
import sys
from pathlib import Path

from ament_index_python.packages import get_package_share_directory

DELIMITER = '=' * 80 + '\n'
# Primitive field types of the ROS 2 .msg language.  rosbag2's list lacks 'wstring' (so it falls
# back to IDL schemas for such types); listing it keeps those types in ros2msg form.
PRIMITIVE_TYPES = frozenset({
    'bool', 'byte', 'char', 'float32', 'float64', 'int8', 'uint8', 'int16', 'uint16', 'int32',
    'uint32', 'int64', 'uint64', 'string', 'wstring'})
# 'pkg/Type' or 'pkg/msg/Type'.
_TYPE_NAME = re.compile(r'^([a-zA-Z][a-zA-Z0-9_]*)/(?:msg/)?([a-zA-Z][a-zA-Z0-9_]*)$')
# The field type at the start of a line ('geometry_msgs/Point' in 'geometry_msgs/Point[] p').
_FIELD_TYPE = re.compile(r'(?:^|\n)\s*([a-zA-Z0-9_/]+)(?:\[[^\]]*\])?\s+')


class DefinitionNotFoundError(LookupError):
    """No installed ``.msg`` file (or type hash) for a message type."""


def type_name(msg_type):
    """Return ``'pkg/msg/Type'`` for a message class or a type name string."""
    if isinstance(msg_type, str):
        package, name = _split(msg_type)
        return f'{package}/msg/{name}'
    package = msg_type.__module__.split('.')[0]
    return f'{package}/msg/{msg_type.__name__}'


def package_share_dir(package):
    """Return the share directory of an installed ROS package."""
    try:
        return Path(get_package_share_directory(package))
    except (LookupError, OSError, ValueError):
        candidate = Path(sys.prefix) / 'share' / package
        if candidate.is_dir():
            return candidate
    raise DefinitionNotFoundError(f'ROS package {package!r} is not installed (no share dir)')


@functools.lru_cache(maxsize=None)
def msg_text(name):
    """Return the installed ``.msg`` text of ``'pkg/Type'`` or ``'pkg/msg/Type'``."""
    package, short = _split(name)
    path = package_share_dir(package) / 'msg' / f'{short}.msg'
    try:
        return path.read_text(encoding='utf-8')
    except FileNotFoundError:
        raise DefinitionNotFoundError(f'no message definition {path}') from None


def dependencies(text, package):
    """Return the sorted non-primitive field types in ``.msg`` text, as ``'pkg/Type'``."""
    found = set()
    for match in _FIELD_TYPE.finditer(text):
        field_type = match.group(1)
        if field_type in PRIMITIVE_TYPES:
            continue
        found.add(field_type if '/' in field_type else f'{package}/{field_type}')
    return sorted(found)


@functools.lru_cache(maxsize=None)
def full_definition(msg_type, root_text=None):
    """Return the ``ros2msg`` schema text of a type, dependencies appended as rosbag2 does.

    ``root_text`` replaces the type's own ``.msg`` text (for a type whose package is not
    installed here); its dependencies still come from the installed ``.msg`` files.
    """
    name = type_name(msg_type)
    seen = set()

    def expand(dep_name, text):
        parts = [text]
        for dep in dependencies(text, _split(dep_name)[0]):
            if dep not in seen:
                seen.add(dep)
                parts += ['\n', DELIMITER, f'MSG: {dep}\n', expand(dep, msg_text(dep))]
        return ''.join(parts)

    return expand(name, msg_text(name) if root_text is None else root_text)


@functools.lru_cache(maxsize=None)
def type_hash(msg_type):
    """Return the ``RIHS01_...`` type hash rosidl generated for an installed type."""
    name = type_name(msg_type)
    package, short = _split(name)
    path = package_share_dir(package) / 'msg' / f'{short}.json'
    try:
        hashes = json.loads(path.read_text(encoding='utf-8'))['type_hashes']
    except FileNotFoundError:
        raise DefinitionNotFoundError(f'no type description {path}') from None
    for entry in hashes:
        if entry['type_name'] == name:
            return entry['hash_string']
    raise DefinitionNotFoundError(f'{path} has no hash for {name}')


@functools.lru_cache(maxsize=None)
def message_class(msg_type):
    """Return the Python class of ``'pkg/msg/Type'``; ``LookupError`` if not importable."""
    package, short = _split(msg_type)
    try:
        return getattr(importlib.import_module(f'{package}.msg'), short)
    except (ImportError, AttributeError):
        raise DefinitionNotFoundError(f'message class {package}.msg.{short} is not '
                                      'installed') from None


def _split(name):
    match = _TYPE_NAME.match(name)
    if match is None:
        raise ValueError(f'not a message type name: {name!r} (expected pkg/msg/Type)')
    return match.group(1), match.group(2)
