"""``/tf_static`` in the plane: where a scan's frame sits in the robot's base frame.

``StaticTransforms.update`` reads a serialized ``tf2_msgs/TFMessage`` straight from its CDR
(``cdr_reader``: tf2_msgs's Python package is needed only to subscribe) and keeps the newest
transform of each child frame, as tf2 does (a frame has one parent).  ``pose(base, frame)``
composes the chain from ``base`` up to the nearest ancestor it shares with ``frame`` and down
to ``frame``, each transform reduced to the plane: ``(x, y, yaw)`` with the yaw of its
rotation (roll, pitch and z are dropped: planar sensors are mounted level).

A transform with a non-finite number is kept as NaN, so a chain through it gives a NaN pose,
which ``pose`` refuses (``ValueError``); so does a malformed message until a readable one
arrives.
"""
import math
import struct

from polyc2bf_ros.cdr_reader import aligned, layout_of, read_string
from polyc2bf_ros.conversions import rotation

IDENTITY = (0.0, 0.0, 0.0)
_NOT_FINITE = (math.nan, math.nan, math.nan)


def planar(values):
    """Return ``(x, y, yaw)`` of a Transform's seven numbers (translation, quaternion x y z w).

    NaN if any of them is not finite: the quaternion's normalisation must not hide one.
    """
    if not all(map(math.isfinite, values)):
        return _NOT_FINITE
    x, y, _, qx, qy, qz, qw = values
    r00, _, _, r10, *_ = rotation(qx, qy, qz, qw)
    return x, y, math.atan2(r10, r00)


def compose(outer, inner):
    """Return the pose ``inner`` (given in the frame of pose ``outer``) in ``outer``'s parent."""
    x, y, yaw = outer
    c, s = math.cos(yaw), math.sin(yaw)
    return x + c * inner[0] - s * inner[1], y + s * inner[0] + c * inner[1], yaw + inner[2]


def invert(pose):
    """Return the pose of the parent frame in the frame of ``pose``."""
    x, y, yaw = pose
    c, s = math.cos(yaw), math.sin(yaw)
    return -c * x - s * y, s * x - c * y, -yaw


def _frame(name):
    """Return a frame id as tf2 compares it: text without a leading slash."""
    return name.decode(errors='replace').lstrip('/')


def read_tf_message(data):
    """Return ``[(parent, child, (x, y, yaw))]`` of a serialized TFMessage; ValueError if bad."""
    layout = layout_of(data)
    try:
        count = layout.length.unpack_from(data, 4)[0]
        if count > len(data):
            raise ValueError(f'{count} transforms in {len(data)} bytes')
        transforms, offset = [], 8
        for _ in range(count):
            offset = aligned(offset, 4) + 8  # header.stamp
            parent, offset = read_string(data, layout, offset)
            child, offset = read_string(data, layout, offset)
            offset = aligned(offset, 8)
            values = layout.pose.unpack_from(data, offset)  # translation, rotation
            offset += layout.pose.size
            transforms.append((_frame(parent), _frame(child), planar(values)))
    except struct.error as exc:
        raise ValueError(f'truncated TFMessage: {exc}') from None
    return transforms


class StaticTransforms:
    """The static transform tree, in the plane (module docstring)."""

    def __init__(self):
        """Start with no transforms."""
        self._parents = {}  # child frame: (parent frame, pose of the child in the parent)
        self.unreadable = ''  # why the last message could not be read ('' if it could)

    def update(self, data):
        """Take one serialized TFMessage; remember why a malformed one could not be read."""
        try:
            transforms = read_tf_message(data)
        except ValueError as exc:
            self.unreadable = f'unreadable /tf_static message: {exc}'
            return
        self.unreadable = ''
        for parent, child, pose in transforms:
            self._parents[child] = (parent, pose)

    def _ancestors(self, frame):
        """Return ``{frame or an ancestor: pose of frame in it}``, nearest first."""
        poses, pose = {frame: IDENTITY}, IDENTITY
        while frame in self._parents:
            frame, step = self._parents[frame]
            if frame in poses:  # a loop: tf2 would refuse it too
                break
            pose = compose(step, pose)
            poses[frame] = pose
        return poses

    def pose(self, base, frame):
        """Return ``(x, y, yaw)`` of ``frame`` in ``base``, or None if no chain links them.

        ``ValueError`` if a transform on the chain is not finite, or the last message was
        unreadable.
        """
        if self.unreadable:
            raise ValueError(self.unreadable)
        from_base = self._ancestors(base)
        for ancestor, pose in self._ancestors(frame).items():
            if ancestor in from_base:
                result = compose(invert(from_base[ancestor]), pose)
                if not all(map(math.isfinite, result)):
                    raise ValueError(f'static transform from {base!r} to {frame!r} is not '
                                     'finite')
                return result
        return None
