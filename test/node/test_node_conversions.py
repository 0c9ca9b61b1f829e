"""Message <-> numpy conversions (no DDS): odometry, commands, CDR, markers, diagnostics."""
import math
import struct

import numpy as np
import pytest
from geometry_msgs.msg import Point, Twist, TwistStamped, WrenchStamped
from hypothesis import given, settings, strategies as st
from rclpy.serialization import deserialize_message, serialize_message
from std_msgs.msg import ColorRGBA
from visualization_msgs.msg import Marker, MarkerArray, UVCoordinate

from node_harness import odometry, wall
from oracles import quaternion_matrix
from polyc2bf_ros import cdr_reader, conversions, diagnostics, marker_obstacles, rviz_markers
from polyc2bf_ros.core.geometry.polygons import point_in_polygon, signed_area, signed_distance
from polyc2bf_ros.core.kernels.quadrotor import rotation_matrix
from polyc2bf_ros.core.obstacles.marker_tracker import ObstacleTracker
from polyc2bf_ros.core.obstacles.obstacle_set import Obstacle, ObstacleSet


def _state(msg, model, dim):
    out = np.zeros(dim)
    yaw = conversions.odometry_to_state(msg, model, out)
    return out, yaw


def _quaternion(roll, pitch, yaw):
    cr, sr = math.cos(roll / 2), math.sin(roll / 2)
    cp, sp = math.cos(pitch / 2), math.sin(pitch / 2)
    cy, sy = math.cos(yaw / 2), math.sin(yaw / 2)
    return (sr * cp * cy - cr * sp * sy, cr * sp * cy + sr * cp * sy,
            cr * cp * sy - sr * sp * cy, cr * cp * cy + sr * sp * sy)


def test_unicycle_and_holonomic_states():
    """Body twist: unicycle keeps (v, omega); point masses rotate it into the odom frame."""
    msg = odometry(1.0, 2.0, math.pi / 2, v=0.5, omega=0.3)
    state, yaw = _state(msg, 'unicycle', 5)
    np.testing.assert_allclose(state, [1.0, 2.0, math.pi / 2, 0.5, 0.3])
    assert yaw == pytest.approx(math.pi / 2)
    state, _ = _state(msg, 'point_mass_2d', 4)
    np.testing.assert_allclose(state, [1.0, 2.0, 0.0, 0.5], atol=1e-12)
    msg.twist.twist.linear.z = -0.2
    state, _ = _state(msg, 'point_mass_3d', 6)
    np.testing.assert_allclose(state, [1.0, 2.0, 0.0, 0.0, 0.5, -0.2], atol=1e-12)


def test_quadrotor_state_matches_the_model_rotation():
    """Roll/pitch/yaw read back exactly; world velocity = R body velocity; body rates kept."""
    msg = odometry()
    roll, pitch, yaw = 0.2, -0.3, 2.5
    q = msg.pose.pose.orientation
    q.x, q.y, q.z, q.w = _quaternion(roll, pitch, yaw)
    msg.twist.twist.linear.x, msg.twist.twist.linear.z = 1.0, 0.5
    msg.twist.twist.angular.x, msg.twist.twist.angular.y = 0.1, 0.2
    state, _ = _state(msg, 'quadrotor', 12)
    np.testing.assert_allclose(state[6:9], [roll, pitch, yaw], atol=1e-12)
    np.testing.assert_allclose(state[3:6], rotation_matrix(roll, pitch, yaw) @ [1.0, 0.0, 0.5])
    np.testing.assert_allclose(state[9:12], [0.1, 0.2, 0.0])


def test_zero_quaternion_is_identity_and_nan_passes_through():
    """An unset orientation reads as identity; NaN stays NaN for the caller to refuse."""
    msg = odometry(v=1.0)
    msg.pose.pose.orientation.w = 0.0
    state, yaw = _state(msg, 'point_mass_2d', 4)
    assert yaw == 0.0 and state[2] == 1.0
    msg.pose.pose.position.x = math.nan
    assert math.isnan(_state(msg, 'unicycle', 5)[0][0])


def test_command_vectors_in_twists_and_wrenches():
    """Command vectors sit in the documented numbers; point masses keep the nominal yaw rate."""
    values = (1.0, 2.0, 3.0, 4.0, 5.0, 6.0)
    assert conversions.command_from_values(values, 'unicycle') == (1.0, 6.0)
    assert conversions.command_from_values(values, 'point_mass_3d') == (1.0, 2.0, 3.0)
    assert conversions.command_from_values(values, 'quadrotor') == (3.0, 4.0, 5.0, 6.0)
    assert conversions.values_from_command((0.1, 0.2), 'point_mass_2d', values) == [
        0.1, 0.2, 0.0, 0.0, 0.0, 6.0]
    assert conversions.values_from_command((0.1, 0.2), 'unicycle', values) == [
        0.1, 0.0, 0.0, 0.0, 0.0, 0.2]
    assert conversions.values_from_command((0.0, 0.0), 'point_mass_2d') == [0.0] * 6
    assert conversions.twist_to_command(_six(TwistStamped, values), 'unicycle') == (1.0, 6.0)
    assert conversions.twist_to_command(_six(Twist, values), 'point_mass_2d') == (1.0, 2.0)
    assert conversions.twist_to_command(_six(WrenchStamped, values), 'quadrotor') == (
        3.0, 4.0, 5.0, 6.0)
    out = Twist()
    conversions.fill_twist(out, 'point_mass_2d', (0.1, 0.2), yaw_rate=0.4)
    assert (out.linear.x, out.linear.y, out.linear.z, out.angular.z) == (0.1, 0.2, 0.0, 0.4)


_FRAMES = st.text(alphabet='abc/_0123456789', max_size=17)
_NUMBERS = st.lists(st.floats(allow_nan=False, allow_infinity=False, width=64),
                    min_size=6, max_size=6)


def _six(msg_type, values):
    msg = msg_type()
    body = msg.twist if msg_type is TwistStamped else msg.wrench if msg_type is WrenchStamped \
        else msg
    first, second = (body.linear, body.angular) if msg_type is not WrenchStamped else (
        body.force, body.torque)
    first.x, first.y, first.z, second.x, second.y, second.z = values
    return msg


@settings(max_examples=60, deadline=None)
@given(msg_type=st.sampled_from([Twist, TwistStamped, WrenchStamped]), frame=_FRAMES,
       values=_NUMBERS, new=_NUMBERS, sec=st.integers(0, 2**31 - 1),
       nanosec=st.integers(0, 999_999_999))
def test_serialized_commands_agree_with_rclpy(msg_type, frame, values, new, sec, nanosec):
    """Reading and rewriting CDR bytes agrees with rclpy's (de)serialisation for any frame_id."""
    msg = _six(msg_type, values)
    stamped = msg_type is not Twist
    if stamped:
        msg.header.frame_id = frame
        msg.header.stamp.sec, msg.header.stamp.nanosec = sec, nanosec
    cmd = conversions.SerializedCommand(serialize_message(msg), stamped)
    assert cmd.values == tuple(values) and cmd.finite
    assert cmd.stamp == (sec + 1e-9 * nanosec if stamped else 0.0)
    assert cmd.stamp_ns == (sec * 1_000_000_000 + nanosec if stamped else 0)
    expected = _six(msg_type, new)
    if stamped:
        expected.header = msg.header
    assert deserialize_message(cmd.replaced(new), msg_type) == expected
    if stamped:
        restamped = deserialize_message(cmd.replaced(new, (7, 8)), msg_type)
        assert (restamped.header.stamp.sec, restamped.header.stamp.nanosec) == (7, 8)
        assert restamped.header.frame_id == frame


@settings(max_examples=60, deadline=None)
@given(frame=_FRAMES, child=_FRAMES, pose=st.lists(st.floats(-1e3, 1e3), min_size=7,
                                                    max_size=7), twist_values=_NUMBERS,
       sec=st.integers(0, 2**31 - 1), nanosec=st.integers(0, 999_999_999))
def test_serialized_odometry_agrees_with_rclpy(frame, child, pose, twist_values, sec, nanosec):
    """``read_odometry`` finds stamp, frames, pose and twist behind any two frame strings."""
    msg = odometry(frame=frame)
    msg.child_frame_id = child
    msg.header.stamp.sec, msg.header.stamp.nanosec = sec, nanosec
    p, q = msg.pose.pose.position, msg.pose.pose.orientation
    p.x, p.y, p.z, q.x, q.y, q.z, q.w = pose
    t = msg.twist.twist
    t.linear.x, t.linear.y, t.linear.z, t.angular.x, t.angular.y, t.angular.z = twist_values
    msg.pose.covariance[:] = 7.0
    msg.twist.covariance[:] = -np.arange(36.0)
    odom = conversions.read_odometry(serialize_message(msg))
    assert (odom.sec, odom.nanosec, odom.stamp) == (sec, nanosec, sec + 1e-9 * nanosec)
    assert (odom.frame.decode(), odom.child_frame.decode()) == (frame, child)
    assert odom.pose == tuple(pose) and odom.twist == tuple(twist_values)


def test_big_endian_and_malformed_bytes():
    """Big-endian CDR reads the same; a foreign encapsulation or truncation is a ValueError."""
    values = (1.0, -2.0, 3.0, 0.0, 0.5, -0.25)
    cmd = conversions.SerializedCommand(b'\x00\x00\x00\x00' + struct.pack('>6d', *values),
                                        stamped=False)
    assert cmd.values == values
    assert deserialize_message(b'\x00\x01\x00\x00' + struct.pack('<6d', *values), Twist) == \
        _six(Twist, values)
    data = serialize_message(_six(TwistStamped, values))
    with pytest.raises(ValueError, match='encapsulation'):
        conversions.SerializedCommand(b'\x00\x07' + data[2:], stamped=True)
    with pytest.raises(ValueError, match='truncated'):
        conversions.SerializedCommand(data[:30], stamped=True)
    with pytest.raises(ValueError, match='truncated'):
        conversions.read_odometry(serialize_message(odometry())[:100])


_TEXT = st.text(st.characters(blacklist_categories=('Cs',), blacklist_characters='\x00'),
                max_size=12)  # what a C string in UTF-8 holds
_FLOATS = st.floats(allow_nan=False, allow_infinity=False, width=64)


@st.composite
def _markers(draw):
    """Draw a Marker with every field set, the ones obstacles skip included."""
    marker = Marker(ns=draw(_TEXT), id=draw(st.integers(-2**31, 2**31 - 1)),
                    type=draw(st.integers(0, 12)), action=draw(st.sampled_from([0, 2, 3])))
    marker.header.frame_id = draw(_FRAMES)
    marker.header.stamp.sec = draw(st.integers(0, 2**31 - 1))
    marker.header.stamp.nanosec = draw(st.integers(0, 999_999_999))
    p, q, scale = marker.pose.position, marker.pose.orientation, marker.scale
    p.x, p.y, p.z, q.x, q.y, q.z, q.w, scale.x, scale.y, scale.z = draw(
        st.lists(_FLOATS, min_size=10, max_size=10))
    marker.frame_locked = draw(st.booleans())
    marker.points = [Point(x=x, y=y, z=z) for x, y, z in draw(
        st.lists(st.tuples(_FLOATS, _FLOATS, _FLOATS), max_size=6))]
    marker.colors = [ColorRGBA(r=0.5)] * draw(st.integers(0, 3))
    marker.texture_resource, marker.text, marker.mesh_resource = (draw(_TEXT) for _ in range(3))
    marker.texture.header.frame_id, marker.texture.format = draw(_TEXT), draw(_TEXT)
    marker.texture.data = draw(st.binary(max_size=9))
    marker.uv_coordinates = [UVCoordinate(u=0.25, v=0.5)] * draw(st.integers(0, 3))
    marker.mesh_file.filename = draw(_TEXT)
    marker.mesh_file.data = draw(st.binary(max_size=9))
    marker.mesh_use_embedded_materials = draw(st.booleans())
    return marker


def _same_marker(view, marker):
    """Assert that the fields a MarkerView carries equal the message's."""
    header, pose = marker.header, marker.pose
    assert view.header.frame_id == header.frame_id
    assert view.header.stamp == (header.stamp.sec, header.stamp.nanosec)
    assert (view.ns, view.id, view.type, view.action) == (marker.ns, marker.id, marker.type,
                                                          marker.action)
    assert view.pose.position == (pose.position.x, pose.position.y, pose.position.z)
    assert view.pose.orientation == (pose.orientation.x, pose.orientation.y,
                                     pose.orientation.z, pose.orientation.w)
    assert view.scale == (marker.scale.x, marker.scale.y, marker.scale.z)
    assert view.points.tolist() == [[p.x, p.y, p.z] for p in marker.points]


@settings(max_examples=60, deadline=None)
@given(markers=st.lists(_markers(), max_size=4))
def test_serialized_marker_arrays_agree_with_rclpy(markers):
    """``read_marker_array`` finds every used field behind any strings, colours and meshes."""
    data = serialize_message(MarkerArray(markers=markers))
    views = cdr_reader.read_marker_array(data).markers
    assert len(views) == len(markers)
    for view, marker in zip(views, markers):
        _same_marker(view, marker)
    for cut in sorted({len(data) - 1, len(data) // 2, 5}):
        if markers:
            with pytest.raises(ValueError, match='truncated|past the end|markers in'):
                cdr_reader.read_marker_array(data[:cut])


def test_marker_views_give_the_obstacles_messages_give():
    """The node's path (serialized -> views) and typed messages build the same obstacle set."""
    tilted = _solid(Marker.CUBE, scale=(1.0, 2.0, 0.5))
    tilted.id = 2
    tilted.pose.orientation.x, tilted.pose.orientation.w = math.sin(0.2), math.cos(0.2)
    msg = MarkerArray(markers=[wall([(2.0, -1.0), (2.0, 1.0)], marker_id=i) for i in range(3)]
                      + [_solid(Marker.CYLINDER, scale=(0.6, 0.6, 1.0)), tilted])
    sets = []
    for given_msg in (msg, cdr_reader.read_marker_array(serialize_message(msg))):
        tracker = ObstacleTracker()
        marker_obstacles.apply_markers(tracker, given_msg, 1.0, 0.05, 12)
        sets.append(tracker.obstacle_set('odom', 3)[0])
    typed, viewed = sets
    assert len(typed) == len(viewed) == 5
    np.testing.assert_array_equal(typed.footprints.vertices, viewed.footprints.vertices)
    np.testing.assert_array_equal(typed.z_ranges, viewed.z_ranges)


def test_big_endian_marker_arrays_read_the_same():
    """CDR in big-endian byte order (encapsulation 0x0000) gives the same views."""
    msg = MarkerArray(markers=[wall([(2.0, -1.0), (2.0, 1.0), (3.0, 0.5)])])
    little = cdr_reader.read_marker_array(serialize_message(msg)).markers[0]
    big = cdr_reader.read_marker_array(_big_endian_marker_array(msg)).markers[0]
    assert big[:7] == little[:7]
    np.testing.assert_array_equal(big.points, little.points)
    assert big.points.dtype == np.float64 and big.points.flags.writeable


def _big_endian_marker_array(msg):
    """Serialize a MarkerArray of LINE_STRIP markers (no optional content) as big-endian CDR."""
    out = bytearray(b'\x00\x00\x00\x00')

    def align(size):
        out.extend(bytes(-(len(out) - 4) % size))

    def put(fmt, *values):
        align(struct.calcsize('>' + fmt.lstrip('0123456789')[0]))
        out.extend(struct.pack('>' + fmt, *values))

    def string(text):
        raw = text.encode() + b'\x00'
        put('I', len(raw))
        out.extend(raw)

    put('I', len(msg.markers))
    for m in msg.markers:
        put('iI', m.header.stamp.sec, m.header.stamp.nanosec)
        string(m.header.frame_id)
        string(m.ns)
        put('3i', m.id, m.type, m.action)
        p, q, s = m.pose.position, m.pose.orientation, m.scale
        put('10d', p.x, p.y, p.z, q.x, q.y, q.z, q.w, s.x, s.y, s.z)
        put('4f', 0.0, 0.0, 0.0, 0.0)
        put('iI', 0, 0)
        put('?', False)
        put('I', len(m.points))
        for point in m.points:
            put('3d', point.x, point.y, point.z)
        put('I', 0)  # colors
        string('')  # texture_resource
        put('iI', 0, 0)
        string('')
        string('')
        put('I', 0)  # texture data
        put('I', 0)  # uv_coordinates
        for _ in range(3):  # text, mesh_resource, mesh_file.filename
            string('')
        put('I', 0)  # mesh_file.data
        put('?', False)
    return bytes(out)


def test_non_finite_odometry_is_refused_even_inside_the_quaternion():
    """An infinite quaternion component would normalise to identity: it is refused instead."""
    pose = (0.0, 0.0, 0.0, 0.0, 0.0, 0.0, math.inf)
    assert conversions.state_from_odometry('unicycle', pose, (0.0,) * 6) is None
    assert conversions.state_from_odometry('quadrotor', (0.0,) * 7, (math.nan,) + (0.0,) * 5) \
        is None


def _solid(kind, position=(1.0, 2.0, 0.5), scale=(2.0, 1.0, 1.0), yaw=0.0):
    marker = Marker(ns='s', id=1, type=kind)
    marker.header.frame_id = 'odom'
    marker.pose.position.x, marker.pose.position.y, marker.pose.position.z = position
    marker.pose.orientation.z, marker.pose.orientation.w = math.sin(yaw / 2), math.cos(yaw / 2)
    marker.scale.x, marker.scale.y, marker.scale.z = scale
    return marker


def test_cube_pose_and_scale():
    """A yawed CUBE: its rotated rectangle, z range from the pose and height, pose position."""
    polygons, z_min, z_max, position = marker_obstacles.marker_geometry(
        _solid(Marker.CUBE, yaw=math.pi / 2), 0.05, 12)
    [polygon] = polygons
    assert signed_area(polygon) == pytest.approx(2.0)
    np.testing.assert_allclose(polygon.min(axis=0), [0.5, 1.0], atol=1e-12)
    assert (z_min, z_max) == pytest.approx((0.0, 1.0))
    np.testing.assert_allclose(position, [1.0, 2.0, 0.5])


@pytest.mark.parametrize('sides', [3, 8, 12])
def test_cylinder_polygon_circumscribes_the_circle(sides):
    """Every point of the cylinder's circle lies inside its polygon."""
    cylinder = _solid(Marker.CYLINDER, scale=(1.0, 1.0, 2.0))
    [polygon], *_ = marker_obstacles.marker_geometry(cylinder, 0.05, sides)
    assert len(polygon) == sides
    circle = np.column_stack([np.cos(np.linspace(0, 2 * np.pi, 200)),
                              np.sin(np.linspace(0, 2 * np.pi, 200))]) * 0.5 + (1.0, 2.0)
    assert all(signed_distance(p, polygon) <= 1e-9 for p in circle)


def test_line_markers():
    """2-point strip: rectangle of the line width; LINE_LIST: one wall per pair; flat z: inf."""
    [polygon], z_min, z_max, position = marker_obstacles.marker_geometry(
        wall([(0.0, 0.0), (2.0, 0.0)], width=0.2), 0.05, 12)
    assert signed_area(polygon) == pytest.approx(2.2 * 0.2)
    assert (z_min, z_max) == (-math.inf, math.inf)
    np.testing.assert_allclose(position, [1.0, 0.0, 0.0])
    marker = wall([(0, 0), (1, 0), (0, 1), (1, 1)], width=0.0)
    marker.type = Marker.LINE_LIST
    polygons, *_ = marker_obstacles.marker_geometry(marker, 0.05, 12)
    assert [signed_area(p) for p in polygons] == pytest.approx([1.05 * 0.05] * 2)


def test_flat_line_strip_with_scale_z_is_a_prism():
    """A flat outline with scale.z > 0 spans [points' z, points' z + scale.z]."""
    marker = wall([(0.0, 0.0), (1.0, 0.0), (1.0, 1.0)], width=0.02)
    for point in marker.points:
        point.z = 0.5
    marker.scale.z = 2.0
    [polygon], z_min, z_max, _ = marker_obstacles.marker_geometry(marker, 0.05, 12)
    assert (z_min, z_max) == (0.5, 2.5)
    assert signed_area(polygon) == pytest.approx(0.5)


def test_triangle_list_applies_pose_and_scale():
    """TRIANGLE_LIST points are scaled, then moved by the pose; z range from the points."""
    marker = _solid(Marker.TRIANGLE_LIST, position=(10.0, 0.0, 0.0), scale=(2.0, 2.0, 1.0))
    marker.points = [Point(x=0.0, y=0.0, z=0.0), Point(x=1.0, y=0.0, z=0.0),
                     Point(x=0.0, y=1.0, z=1.0)]
    [polygon], z_min, z_max, _ = marker_obstacles.marker_geometry(marker, 0.05, 12)
    assert signed_area(polygon) == pytest.approx(2.0)
    assert point_in_polygon((10.5, 0.5), polygon)
    assert (z_min, z_max) == (0.0, 1.0)


@pytest.mark.parametrize('edit, reason', [
    (lambda m: setattr(m.pose.position, 'x', math.nan), 'non-finite'),
    (lambda m: setattr(m, 'type', Marker.ARROW), 'unsupported marker type ARROW'),
    (lambda m: setattr(m, 'type', Marker.LINE_LIST), 'multiple of 2'),
    (lambda m: setattr(m, 'points', []), 'no points'),
])
def test_bad_markers_raise_a_reason(edit, reason):
    """NaN, unsupported types, odd LINE_LISTs and empty outlines are refused with a reason."""
    marker = wall([(0, 0), (1, 0), (1, 1)])
    edit(marker)
    with pytest.raises(ValueError, match=reason):
        marker_obstacles.marker_geometry(marker, 0.05, 12)


def test_apply_markers_actions_frames_and_stamps():
    """ADD/DELETE/DELETEALL, labels skipped, empty frame and NaN rejected, zero stamp = now."""
    tracker = ObstacleTracker()
    nan_wall = wall([(0, 0), (math.nan, 1)], marker_id=3)
    no_frame = wall([(0, 0), (1, 0)], marker_id=4, frame='')
    label = Marker(ns='walls', id=5, type=Marker.TEXT_VIEW_FACING)
    msg = MarkerArray(markers=[wall([(0, 0), (1, 0)], marker_id=1),
                               wall([(0, 2), (1, 2)], marker_id=2), nan_wall, no_frame, label])
    marker_obstacles.apply_markers(tracker, msg, 42.0, 0.05, 12)
    assert len(tracker) == 2 and tracker.has_invalid
    assert set(tracker.rejected) == {'walls/3', 'walls/4'}
    assert 'frame' in tracker.rejected['walls/4']
    assert tracker.snapshot('odom', 2)[1] == 42.0
    marker_obstacles.apply_markers(tracker, MarkerArray(markers=[
        Marker(ns='walls', id=1, action=Marker.DELETE),
        Marker(ns='walls', id=3, action=Marker.DELETE)]), 43.0, 0.05, 12)
    assert len(tracker) == 1 and not tracker.has_invalid
    marker_obstacles.apply_markers(tracker, MarkerArray(markers=[
        Marker(action=Marker.DELETEALL)]), 44.0, 0.05, 12)
    assert len(tracker) == 0 and tracker.rejected == {}


def _vertex_set(polygon):
    """Rows of ``polygon`` sorted, rounded to 1e-9 (start vertex and order ignored)."""
    return np.round(polygon[np.lexsort(polygon.T[::-1])], 9) + 0.0


def _moving_markers():
    """Markers of every usable kind with a yaw; one tilted CUBE."""
    cube, cylinder = _solid(Marker.CUBE, yaw=0.3), _solid(Marker.CYLINDER, yaw=1.0)
    cylinder.id = 2
    outline = wall([(0.0, 0.0), (1.0, 0.0), (1.0, 1.0), (0.5, 0.3)], ns='moving', width=0.02)
    outline.pose.orientation.z, outline.pose.orientation.w = math.sin(0.2), math.cos(0.2)
    triangles = _solid(Marker.TRIANGLE_LIST, scale=(1.0, 2.0, 1.0), yaw=-0.5)
    triangles.id = 3
    triangles.points = [Point(x=0.0, y=0.0), Point(x=1.0, y=0.0), Point(x=0.0, y=1.0),
                        Point(x=2.0, y=0.0), Point(x=3.0, y=0.0), Point(x=2.0, y=1.0)]
    tilted = _solid(Marker.CUBE)
    tilted.id = 4
    q = tilted.pose.orientation
    q.x, q.y, q.z, q.w = _quaternion(0.4, 0.0, 0.2)
    return [cube, cylinder, outline, triangles, tilted]


def test_moved_markers_reuse_their_shape():
    """Same shape, new pose: the Shape object is reused and the obstacles are right.

    Reference: the shape computed from scratch with the whole rotation applied
    to the points before the outline / hull (an independent path).
    """
    tracker = ObstacleTracker()
    markers = _moving_markers()
    marker_obstacles.apply_markers(tracker, MarkerArray(markers=markers), 1.0, 0.05, 12)
    keys = [f'{m.ns}/{m.id}' for m in markers]
    shapes = [tracker.shape(key) for key in keys]
    for i, marker in enumerate(markers):
        marker.pose.position.x += 0.5 * i
        marker.pose.position.z -= 0.1
        q = marker.pose.orientation
        if q.x == 0.0:   # turn the yawed ones further; the tilted one keeps its tilt
            q.z, q.w = _quaternion(0.0, 0.0, 2.0 * math.atan2(q.z, q.w) + 0.7)[2:]
    marker_obstacles.apply_markers(tracker, MarkerArray(markers=markers), 1.1, 0.05, 12)
    assert [tracker.shape(key) for key in keys] == shapes
    obstacles = {o.key: o for o in tracker.snapshot('odom', 3)[0]}
    for key, marker in zip(keys, markers):
        tilt = quaternion_matrix(marker.pose.orientation)
        fresh = marker_obstacles.marker_shape(marker, 0.05, 12, tilt)
        origin = marker_obstacles.marker_placement(marker)[0]
        for i, polygon in enumerate(fresh.polygons):
            obstacle = obstacles[key if len(fresh.polygons) == 1 else f'{key}#{i}']
            np.testing.assert_array_equal(_vertex_set(obstacle.polygon),
                                          _vertex_set(polygon + origin[:2]))
            assert obstacle.z_min == pytest.approx(fresh.z_min + origin.z)
            assert obstacle.z_max == pytest.approx(fresh.z_max + origin.z)


def test_changed_shapes_and_settings_are_rebuilt_and_bad_poses_still_refused():
    """New points, scale or wall thickness make a new Shape; NaN poses are refused as before."""
    tracker = ObstacleTracker()
    outline = wall([(0.0, 0.0), (2.0, 0.0)], width=0.0)
    robot = _solid(Marker.CYLINDER)
    marker_obstacles.apply_markers(tracker, MarkerArray(markers=[outline, robot]), 1.0, 0.05, 12)
    first_wall, first_robot = tracker.shape('walls/0'), tracker.shape('s/1')
    marker_obstacles.apply_markers(tracker, MarkerArray(markers=[outline, robot]), 1.1, 0.1, 12)
    assert tracker.shape('walls/0') is not first_wall          # wall_thickness changed
    assert signed_area(tracker.shape('walls/0').polygons[0]) == pytest.approx(2.1 * 0.1)
    robot.scale.x = robot.scale.y = 2.0
    outline.points[1].x = 4.0
    marker_obstacles.apply_markers(tracker, MarkerArray(markers=[outline, robot]), 1.2, 0.1, 12)
    assert tracker.shape('s/1') is not first_robot
    assert signed_area(tracker.shape('walls/0').polygons[0]) == pytest.approx(4.1 * 0.1)
    [polygon] = tracker.shape('s/1').polygons
    assert np.linalg.norm(polygon, axis=1).max() == pytest.approx(1.0 / math.cos(math.pi / 12))
    robot.pose.orientation.w = math.nan
    outline.pose.position.y = math.inf
    marker_obstacles.apply_markers(tracker, MarkerArray(markers=[outline, robot]), 1.3, 0.1, 12)
    assert tracker.has_invalid and len(tracker) == 0
    assert tracker.rejected == {'s/1': 'non-finite pose or scale',
                                'walls/0': 'non-finite pose, scale or points'}


def test_filter_markers_and_diagnostics():
    """Markers: DELETEALL, one outline per part (active in red), cones only when given."""
    obstacles = ObstacleSet.from_obstacles([])
    plain = rviz_markers.filter_markers('odom', odometry().header.stamp,
                                       obstacles.footprints, active=())
    assert [m.action for m in plain.markers] == [Marker.DELETEALL]
    obstacles = ObstacleSet.from_obstacles([
        Obstacle(polygon=np.array([[1.0, -1.0], [2.0, -1.0], [2.0, 1.0], [1.0, 1.0]]))])

    class Cones:
        p = np.array([[1.5], [0.0]])  # (2, N) planar vectors, as the core's Cones
        k = np.array([[1.0], [1.0]])

    drawn = rviz_markers.filter_markers('odom', odometry().header.stamp, obstacles.footprints,
                                       active=[0], apex=(0.0, 0.0), cones=Cones())
    outline, cone = drawn.markers[1:]
    assert outline.color.r > 0.5 and len(outline.points) == 5
    assert [(p.x, p.y) for p in cone.points] == [(0, 0), (1, 1), (0, 0), (1, -1)]
    # The ground part the filter adds (index past the footprints) is active but not drawn.
    grounded = rviz_markers.filter_markers('odom', odometry().header.stamp,
                                           obstacles.footprints, active=[1])
    assert [m.color.r < 0.5 for m in grounded.markers[1:]] == [True]
    # The body: a footprint turned to the heading and moved to the base, closed.
    body = rviz_markers.body_outline(np.array([1.0, 2.0]), 0.5 * np.pi,
                                     np.array([[0.5, 0.2], [-0.5, 0.2], [-0.5, -0.2]]), 0.3)
    assert np.allclose(body, [[0.8, 2.5], [0.8, 1.5], [1.2, 1.5]])
    robot = rviz_markers.filter_markers('odom', odometry().header.stamp, obstacles.footprints,
                                        active=(), body=body).markers[-1]
    assert robot.ns == 'robot' and [(p.x, p.y) for p in robot.points][::3] == [(0.8, 2.5)] * 2
    array = diagnostics.diagnostic_array(odometry().header.stamp, 'f', 'unicycle', b'\x01',
                                         'msg', {'a': 1, 'b': 'x'})
    [status] = array.status
    assert [(kv.key, kv.value) for kv in status.values] == [('a', '1'), ('b', 'x')]
