"""The bridge's obstacle markers: each footprint of a ``SimWorld`` as the Marker it publishes.

``ObstacleMarkers`` makes each marker once (``bridge_node``'s docstring: a static prism's
``LINE_STRIP`` outline, a moving one's outline about its pose, a robot's ``CYLINDER``) and
moves the dynamic ones to their footprints' current places.
"""
import numpy as np
from geometry_msgs.msg import Point
from std_msgs.msg import ColorRGBA
from visualization_msgs.msg import Marker

LINE_WIDTH = 0.02
COLORS = {'static': ColorRGBA(r=0.6, g=0.6, b=0.6, a=0.9),
          'moving': ColorRGBA(r=1.0, g=0.5, b=0.0, a=0.9),
          'robot': ColorRGBA(r=0.2, g=0.4, b=1.0, a=0.6)}


def _point(x, y, z=0.0):
    return Point(x=float(x), y=float(y), z=float(z))


class ObstacleMarkers:
    """The markers of a world's footprints in ``frame``, made on first sight and then reused."""

    def __init__(self, world, frame):
        """Remember the world and the frame; no marker is made yet."""
        self.world = world
        self.frame = frame
        self._markers = {}  # (footprint.robot, footprint.index) -> (Marker, dynamic)

    def current(self, time_msg, full):
        """Return [(robot name or None, Marker)] to send: dynamic ones moved, all if ``full``.

        Moving obstacles and robots are dynamic (marker pose = footprint centre);
        static obstacles go out only in full sets.  Every marker is stamped.
        """
        markers = []
        for footprint in self.world.obstacle_footprints(moving_only=not full):
            marker, dynamic = self._marker(footprint)
            if dynamic:
                position = marker.pose.position
                position.x, position.y = footprint.polygon.mean(axis=0).tolist()
                if footprint.robot:
                    position.z = 0.5 * (footprint.z_min + footprint.z_max)
            marker.header.stamp = time_msg
            markers.append((footprint.name if footprint.robot else None, marker))
        return markers

    def _marker(self, footprint):
        """Return (Marker, dynamic) of a footprint, made on first sight and then reused."""
        key = (footprint.robot, footprint.index)
        entry = self._markers.get(key)
        if entry is None:
            if footprint.robot:
                entry = (self._robot_marker(footprint), True)
            else:
                kind = 'moving' if np.any(footprint.velocity) else 'static'
                entry = (self._outline_marker(footprint, kind), kind == 'moving')
            self._markers[key] = entry
        return entry

    def _outline_marker(self, footprint, kind):
        """LINE_STRIP outline at z_min, height in scale.z; moving ones relative to their pose."""
        centre = footprint.polygon.mean(axis=0) if kind == 'moving' else np.zeros(2)
        ring = np.vstack([footprint.polygon, footprint.polygon[:1]]) - centre
        marker = Marker(ns='obstacles', id=footprint.index, type=Marker.LINE_STRIP,
                        action=Marker.ADD,
                        color=COLORS[kind], points=[_point(x, y) for x, y in ring])
        marker.header.frame_id = self.frame
        marker.scale.x = LINE_WIDTH
        marker.scale.z = footprint.z_max - footprint.z_min
        marker.pose.position = _point(*centre, footprint.z_min)
        marker.pose.orientation.w = 1.0
        return marker

    def _robot_marker(self, footprint):
        """CYLINDER of the robot's footprint radius over its z range."""
        marker = Marker(ns='robots', id=footprint.index, type=Marker.CYLINDER,
                        action=Marker.ADD, color=COLORS['robot'], text=footprint.name)
        marker.header.frame_id = self.frame
        diameter = 2.0 * self.world.robot_spec(footprint.name).radius
        marker.scale.x = marker.scale.y = diameter
        marker.scale.z = footprint.z_max - footprint.z_min
        marker.pose.orientation.w = 1.0
        return marker
