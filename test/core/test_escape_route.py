"""``escape_route``: the clearance grid, the route past a wall or out of a pocket, following."""
import math
from types import SimpleNamespace

import numpy as np
import pytest
from hypothesis import given, strategies as st

from polyc2bf_ros.core.barrier.cones import PlanarPolygons
from polyc2bf_ros.core.geometry.polygons import signed_distance
from polyc2bf_ros.core.kernels.route import grid_clearance
from polyc2bf_ros.core.liveness.escape_route import (
    BACKING_SPEED,
    MAX_WIDEN,
    PATIENCE,
    plan_route,
    REPLAN_LOSS,
    route_clearances,
    RouteEscape,
    SEEN_AROUND,
    unseen_cells,
    WIDEN,
)
from polyc2bf_ros.core.obstacles.obstacle_set import Obstacle, ObstacleSet
from polyc2bf_ros.core.obstacles.scan_memory import ScanView
from strategies import convex_polygons
from test_circulation import evaluation_with_axes

FREE = 0.522
RUN = 1.5   # m: config/jackal.yaml's route_clear_run


def box(x0, y0, x1, y1):
    """Return the CCW rectangle [x0, x1] x [y0, y1]."""
    return np.array([[x0, y0], [x1, y0], [x1, y1], [x0, y1]], dtype=float)


def obstacle_set(*polygons):
    """Return the ``ObstacleSet`` of static ``polygons``."""
    return ObstacleSet.from_obstacles([Obstacle(polygon=p, key=str(i))
                                       for i, p in enumerate(polygons)])


def clearance_along(route, polygons):
    """Return the smallest signed distance of each route point to ``polygons``."""
    return np.array([min(signed_distance(point, p) for p in polygons) for point in route])


@given(st.lists(convex_polygons(centre_range=3.0, max_size=1.5), min_size=1, max_size=4),
       st.floats(-4.0, 4.0), st.floats(-4.0, 4.0), st.floats(0.3, 3.0))
def test_grid_clearance_is_the_signed_distance_capped_at_the_cutoff(polygons, x0, y0, cutoff):
    """Every cell centre: min(cutoff, min_n signed distance to polygon n)."""
    prepared = PlanarPolygons.from_batch(obstacle_set(*polygons).footprints)
    out = np.empty((9, 11))
    grid_clearance(prepared.x, prepared.y, prepared.edge_x, prepared.edge_y, prepared.inv_sq,
                   np.ascontiguousarray(prepared.counts, dtype=np.int64), x0, y0, 0.37, cutoff,
                   out)
    for i in range(out.shape[0]):
        for j in range(out.shape[1]):
            point = (x0 + 0.37 * j, y0 + 0.37 * i)
            expected = min(cutoff, min(signed_distance(point, p) for p in polygons))
            assert out[i, j] == pytest.approx(expected, abs=1e-9)


def test_the_route_goes_round_the_wall_ahead_keeping_the_clearance():
    """A 3 m wall 0.6 m ahead: the route rounds one end and ends 3 m ahead, never too close."""
    wall = box(2.0, -1.5, 2.3, 1.5)
    route = plan_route(obstacle_set(wall), (1.45, 0.2), (1.0, 0.0), FREE)
    assert route is not None
    np.testing.assert_allclose(route[0], (1.45, 0.2))
    assert route[-1, 0] - 1.45 >= 3.0 - 1e-9
    clear = clearance_along(route, [wall])
    far = np.hypot(*(route - (1.45, 0.2)).T) > 0.35   # past the start band
    assert clear[far].min() >= FREE - 1e-9 and clear.min() >= min(FREE, clear[0]) - 1e-9
    beside = route[(route[:, 0] > 2.0) & (route[:, 0] < 2.3)]
    assert len(beside) and np.abs(beside[:, 1]).min() >= 1.5 + FREE - 1e-9
    assert np.all(np.hypot(*np.diff(route, axis=0).T) <= 0.1 * math.sqrt(2) + 0.06)


def run_clearance(end, direction, polygons, length=RUN):
    """Return the least clearance along the straight run ``length`` from ``end``."""
    steps = np.linspace(0.0, length, int(length / 0.02) + 1)[:, None]
    return clearance_along(np.asarray(end) + steps * np.asarray(direction), polygons).min()


def test_the_route_ends_where_the_way_on_along_the_intent_is_clear():
    """Two staggered walls: the route ends where the second leaves the way on clear.

    Ended 3 m ahead as the rule without the run (``route_clear_run`` 0) has it, the
    nominal drives on straight into the second wall and is held again.  With no clear run
    anywhere in the window (a wall across all of it), the route ends where that rule ends it.
    """
    start, near = (1.45, 0.0), box(2.0, -4.8, 2.3, 1.0)
    far = box(5.6, -1.0, 5.9, 4.8)
    walls = obstacle_set(near, far)
    route = plan_route(walls, start, (1.0, 0.0), FREE, run=RUN)
    short = plan_route(walls, start, (1.0, 0.0), FREE)
    assert route is not None and short is not None
    assert run_clearance(short[-1], (1.0, 0.0), [near, far]) < FREE     # the second wall
    reach = min(RUN, start[0] + 5.0 - route[-1, 0])   # the window's edge: unknown
    assert run_clearance(route[-1], (1.0, 0.0), [near, far], reach) >= FREE - 0.1 * math.sqrt(2)
    assert route[-1, 0] - start[0] >= 3.0 - 1e-9
    across = obstacle_set(near, box(6.0, -6.0, 6.3, 6.0))
    fallback = plan_route(across, start, (1.0, 0.0), FREE, run=RUN)
    assert fallback is not None
    np.testing.assert_allclose(fallback, plan_route(across, start, (1.0, 0.0), FREE))


def quarter_view(start, wall_x, wall_top):
    """Return the ``ScanView`` of a laser at ``start`` facing +x, beams over [0, 90] degrees.

    Its beams stop at the face x = ``wall_x`` of a wall up to y = ``wall_top``; above it they
    pass.  Everything at negative bearings lies in its blind sector.
    """
    step = math.radians(0.5)
    bearings = np.arange(0.0, 0.5 * math.pi + 1e-9, step)
    distance = wall_x - start[0]
    ranges = np.where(start[1] + distance * np.tan(bearings) <= wall_top,
                      distance / np.cos(bearings), np.inf)
    return ScanView(start[0], start[1], 0.0, 0.0, float(bearings[-1]), step, 0.05, 10.0,
                    start, ranges)


def test_unseen_cells_are_those_no_beam_reached():
    """Behind the wall and in the blind sector: unseen; before it and near the robot: seen."""
    start, cell, count = (0.5, 0.0), 0.1, 61
    x0, y0 = start[0] - 3.0, start[1] - 3.0
    unseen = unseen_cells((quarter_view(start, 2.0, 2.0),), x0, y0, cell, count, start)

    def at(x, y):
        return unseen[int(round((y - y0) / cell)), int(round((x - x0) / cell))]

    assert at(1.5, 1.0) == 0.0 and at(1.9, 0.1) == 0.0    # lit, before the wall's face
    assert at(1.0, 2.8) == 0.0                            # above the wall: the beams passed
    assert at(3.0, 1.0) == 1.0 and at(2.5, 0.1) == 1.0    # behind the wall
    assert at(1.5, -1.0) == 1.0 and at(-1.0, 0.5) == 1.0  # in the blind sector
    assert at(start[0] + 0.8 * SEEN_AROUND, -0.1) == 0.0  # where the robot stands
    assert not unseen_cells((), x0, y0, cell, count, start).any()   # markers: all seen


def test_the_route_keeps_to_what_the_laser_saw():
    """A wall ahead, shorter round its lower end: that side is unseen, so the route goes over.

    Without a view (obstacles from markers) the shorter way round stands.
    """
    start, wall = (0.5, 0.0), box(2.0, -1.0, 2.3, 2.0)
    blind = plan_route(obstacle_set(wall), start, (1.0, 0.0), FREE)
    seen = plan_route(obstacle_set(wall), start, (1.0, 0.0), FREE,
                      views=(quarter_view(start, 2.0, 2.0),))
    assert blind is not None and seen is not None
    assert blind[:, 1].min() < -1.0 - FREE + 1e-9 and blind[:, 1].max() <= start[1] + 1e-9
    assert seen[:, 1].max() > 2.0 + FREE - 1e-9 and seen[:, 1].min() >= start[1] - 1e-9
    assert seen[-1, 0] - start[0] >= 3.0 - 1e-9
    far = np.hypot(*(seen - start).T) > 0.35
    assert clearance_along(seen[far], [wall]).min() >= FREE - 1e-9


def test_from_a_held_robot_the_route_never_starts_closer_to_a_part():
    """Held 0.45 m from a box (under c_min): no route point comes closer than that.

    A first step that loses clearance points into the cone of the part it nears, and the
    filter refuses it from the boundary.
    """
    post = box(1.0, 0.3, 1.3, 0.6)
    start = (0.8, 0.3 - 0.45 / math.sqrt(2) + 0.2)
    held = signed_distance(start, post)
    assert held < FREE
    route = plan_route(obstacle_set(post), start, (-1.0, 0.3), FREE)
    assert route is not None
    assert clearance_along(route, [post]).min() >= held - 1e-9


def test_the_route_backs_out_of_a_pocket():
    """Held at the back of a U open behind the robot: the route leaves the way it came."""
    walls = [box(4.0, -1.5, 4.3, 1.5), box(1.5, 1.5, 4.3, 1.8), box(1.5, -1.8, 4.3, -1.5)]
    route = plan_route(obstacle_set(*walls), (3.45, 0.0), (1.0, 0.0), FREE, window=12.0)
    assert route is not None
    assert route[:, 0].min() < 1.5 - FREE      # out past the open end
    assert route[-1, 0] >= 3.45 + 3.0 - 1e-9   # then on beyond the back wall
    far = np.hypot(*(route - (3.45, 0.0)).T) > 0.35
    assert clearance_along(route[far], walls).min() >= FREE - 1e-9


def test_no_route_out_of_a_closed_box_falls_back_to_circulation():
    """Walled in on all sides: no route; with a cone seen, circulation takes over."""
    walls = [box(-1.5, -1.5, 1.5, -1.2), box(-1.5, 1.2, 1.5, 1.5), box(-1.5, -1.2, -1.2, 1.2),
             box(1.2, -1.2, 1.5, 1.2)]
    obstacles = obstacle_set(*walls)
    assert plan_route(obstacles, (0.6, 0.0), (1.0, 0.0), FREE) is None
    escape = RouteEscape(FREE)
    escape.observe(SimpleNamespace(h=np.array([0.05]),
                                   evaluation=evaluation_with_axes((0.6, 0.0), [True])))
    escape.engage(0.0, (0.6, 0.0), 0.1, (0.8, 0.0), obstacles)
    assert escape.active and escape.side == 1 and escape.routes == 0
    assert escape.engagements == 1 and escape.mode == 'circulate'


def test_following_turns_onto_the_route_then_drives_and_releases_at_its_end():
    """Facing the wall: turn toward the route's side; aligned: the held speed; end: release."""
    wall = box(2.0, -1.5, 2.3, 1.5)
    escape = RouteEscape(FREE, lookahead=0.5)
    assert escape.mode == 'none'
    escape.engage(0.0, (1.45, 0.2), 0.0, (0.7, 0.0), obstacle_set(wall))
    assert escape.active and escape.routes == 1 and escape.side == 0
    assert escape.mode == 'route'
    route = escape._route
    v, omega = escape.command(0.0, (0.0, 0.0), (1.45, 0.2))
    assert v == 0.0 and omega == 0.0                        # a nominal stop stays a stop
    v, omega = escape.command(0.0, (0.7, 0.0), (1.45, 0.2))
    turn = math.copysign(1.0, route[5, 1] - 0.2)             # the side the route takes
    assert omega * turn > 0.0
    heading = math.atan2(*(route[5] - route[0])[::-1])
    v, _ = escape.command(heading, (0.0, -1.0), route[0])    # the report's |v| is kept
    assert v == pytest.approx(0.7, rel=0.1)
    escape.release_if_done(1.0, route[len(route) // 2], lambda: True)
    assert escape.active                                     # the probe does not end a route
    for point in route[len(route) // 2:]:                   # drive on along it
        escape.release_if_done(2.0, point, lambda: False)
    assert not escape.active


@pytest.mark.parametrize('backing', [0.0, 0.14])
def test_a_box_backs_out_first_and_drives_to_points_behind_in_reverse(backing):
    """Nose-in at a wall: the route of a box starts ``backing`` behind it, driven in reverse.

    A disc (backing 0) plans from where it stands and never reverses.
    """
    wall = box(2.0, -1.5, 2.3, 1.5)
    escape = RouteEscape(FREE, lookahead=0.1, backing=backing)
    escape.engage(0.0, (1.45, 0.2), 0.0, (0.7, 0.0), obstacle_set(wall))
    route = escape._route
    assert route[0].tolist() == [1.45, 0.2]
    v, omega = escape.command(0.0, (0.7, 0.0), (1.45, 0.2))
    if backing:
        assert route[1, 0] <= 1.45 - backing + 0.1  # the backed point's cell, then on
        assert -BACKING_SPEED <= v < 0.0 and abs(omega) < 0.5  # straight back, slowly
    else:
        assert v >= 0.0
    # Facing away from a point behind, forward is never asked of a box in reverse.
    v, _ = escape.command(math.pi, (0.7, 0.0), (1.45, 0.2))
    assert v >= 0.0
    # Past the backing leg a point behind is turned to, never reversed to.
    far = int(np.searchsorted(escape._arc, backing + 0.3))
    ahead = route[min(far + 2, len(route) - 1)] - route[far]
    v, _ = escape.command(math.atan2(ahead[1], ahead[0]) + math.pi, (0.7, 0.0), route[far])
    assert v >= 0.0


def test_a_route_ends_after_its_time_limit_and_a_second_report_replans():
    """max(max_time, 3 L / v_n) after the report the nominal takes over; a new report plans."""
    wall = box(2.0, -1.5, 2.3, 1.5)
    obstacles = obstacle_set(wall)
    escape = RouteEscape(FREE, max_time=5.0)
    escape.engage(0.0, (1.45, 0.2), 0.0, (1.0, 0.0), obstacles)
    length = float(np.hypot(*np.diff(escape._route, axis=0).T).sum())
    start = escape._route[0]
    for k, now in enumerate(np.arange(0.5, 3.0 * length - 0.1, 0.5)):
        # to and fro 0.15 m near the start: moving, never near the end
        escape.release_if_done(now, start + (0.15 * (k % 2), 0.0), lambda: True)
    assert escape.active
    escape.engage(3.0 * length - 0.05, (1.45, 0.2), 0.0, (1.0, 0.0), obstacles)
    assert escape.routes == 2
    escape.release_if_done(6.0 * length, (1.45, 0.2), lambda: True)
    assert not escape.active


def test_a_standing_part_lit_on_the_route_ahead_plans_it_again_round_the_part():
    """A post found on the route ahead: a new route from where the robot is, clear of it.

    The same parts in a new set, a part that moves, or a post beside the route (nearer
    than before by less than ``REPLAN_LOSS``, or farther than c_min) leave the route as it
    is; with no route round the post the old one is kept.
    """
    wall = box(2.0, -1.5, 2.3, 1.5)
    escape = RouteEscape(FREE, lookahead=0.25)
    escape.engage(0.0, (1.45, 0.2), 0.0, (0.7, 0.0), obstacle_set(wall))
    first = escape._route.copy()
    middle = len(first) // 2
    here = first[middle // 2]
    escape.release_if_done(1.0, here, lambda: True)
    assert not escape.revise(1.0, here, 0.0, (0.7, 0.0), obstacle_set(wall))
    ahead = first[middle + 3]
    post = box(*(ahead - 0.1), *(ahead + 0.1))
    moving = ObstacleSet.from_obstacles([
        Obstacle(polygon=wall, key='wall'),
        Obstacle(polygon=post, velocity=np.array([0.5, 0.0, 0.0]), key='post')])
    assert not escape.revise(1.0, here, 0.0, (0.7, 0.0), moving)
    aside = escape._allowed[middle + 3] - REPLAN_LOSS + 0.02   # a post off the route
    beside = box(ahead[0] - 0.1, ahead[1] + aside, ahead[0] + 0.1, ahead[1] + aside + 0.2)
    assert not escape.revise(1.0, here, 0.0, (0.7, 0.0), obstacle_set(wall, beside))
    np.testing.assert_array_equal(escape._route, first)
    lit = obstacle_set(wall, post)
    assert escape.revise(1.5, here, 0.0, (0.7, 0.0), lit)
    assert escape.replans == 1 and escape.routes == 1 and escape.active
    route = escape._route
    np.testing.assert_allclose(route[0], here)
    far = np.hypot(*(route - here).T) > 0.35   # past the start band
    assert clearance_along(route[far], [wall, post]).min() >= FREE - 1e-9
    assert not escape.revise(1.6, here, 0.0, (0.7, 0.0), lit)   # checked: no new plan
    boxed = RouteEscape(FREE, lookahead=0.25)
    boxed.engage(0.0, (1.45, 0.2), 0.0, (0.7, 0.0), obstacle_set(wall))
    cage = [box(-0.5, -0.5, 3.5, -0.4), box(-0.5, 0.8, 3.5, 0.9), box(-0.5, -0.5, -0.4, 0.9)]
    kept = boxed._route.copy()
    caged = obstacle_set(wall, *cage)
    assert np.any(route_clearances(caged, kept, FREE) < boxed._allowed - REPLAN_LOSS)
    assert not boxed.revise(1.0, (1.45, 0.2), 0.0, (0.7, 0.0), caged)
    np.testing.assert_array_equal(boxed._route, kept)
    assert boxed.replans == 0


def test_a_holonomic_base_follows_the_route_with_a_body_frame_velocity():
    """point_mass_2d: the way and the command are velocities, turned by the odometry yaw.

    The way is the nominal velocity in the world; the command the velocity towards the
    target at the report's speed, turned back into the body frame.  No route: no fallback.
    """
    wall = box(2.0, -1.5, 2.3, 1.5)
    escape = RouteEscape(FREE, holonomic=True)
    yaw = math.pi / 2                                     # body x is world +y
    escape.engage(0.0, (1.45, 0.2), yaw, (0.0, -0.8), obstacle_set(wall))  # world +x
    assert escape.active and escape.routes == 1
    route = escape._route
    assert route[-1, 0] - 1.45 >= 3.0 - 1e-9
    command = escape.command(yaw, (0.0, -0.1), route[0])
    assert np.hypot(*command) == pytest.approx(0.8)
    c, s = math.cos(yaw), math.sin(yaw)
    world = np.array([c * command[0] - s * command[1], s * command[0] + c * command[1]])
    target = route[np.searchsorted(escape._arc, escape.lookahead)]
    toward = (target - route[0]) / np.linalg.norm(target - route[0])
    np.testing.assert_allclose(world / 0.8, toward, atol=1e-9)
    walls = [box(-1.5, -1.5, 1.5, -1.2), box(-1.5, 1.2, 1.5, 1.5), box(-1.5, -1.2, -1.2, 1.2),
             box(1.2, -1.2, 1.5, 1.2)]
    boxed = RouteEscape(FREE, holonomic=True)
    boxed.engage(0.0, (0.6, 0.0), 0.0, (0.8, 0.0), obstacle_set(*walls))
    assert not boxed.active and boxed.engagements == 1
    nominal = np.array([0.8, 0.0])
    assert boxed.command(0.0, nominal, (0.6, 0.0)) is nominal


def test_after_no_route_a_lasting_deadlock_plans_again_only_after_max_time():
    """The held steps that follow a failed plan do not each plan again (1 ms apiece)."""
    walls = [box(-1.5, -1.5, 1.5, -1.2), box(-1.5, 1.2, 1.5, 1.5), box(-1.5, -1.2, -1.2, 1.2),
             box(1.2, -1.2, 1.5, 1.2)]
    obstacles = obstacle_set(*walls)
    escape = RouteEscape(FREE, holonomic=True, max_time=10.0)
    escape.engage(0.0, (0.6, 0.0), 0.0, (0.8, 0.0), obstacles)
    for now in (0.01, 5.0, 9.99):
        escape.engage(now, (0.6, 0.0), 0.0, (0.8, 0.0), obstacles, renew=True)
    assert escape.engagements == 1
    escape.engage(10.0, (0.6, 0.0), 0.0, (0.8, 0.0), obstacles, renew=True)
    escape.engage(10.5, (0.6, 0.0), 0.0, (0.8, 0.0), obstacles)   # a new report: at once
    assert escape.engagements == 3 and not escape.active


def test_a_blocked_route_is_planned_again_wider_then_circulation_takes_over():
    """Not 0.1 m on in PATIENCE s: blocked; each next plan keeps WIDEN more, up to MAX_WIDEN."""
    wall = box(2.0, -1.5, 2.3, 1.5)
    obstacles = obstacle_set(wall)
    escape = RouteEscape(FREE)
    escape.observe(SimpleNamespace(h=np.array([0.05]),
                                   evaluation=evaluation_with_axes((0.55, 0.0), [True])))
    now, clearances = 0.0, []
    for blocked in range(MAX_WIDEN + 1):
        escape.engage(now, (1.45, 0.2), 0.0, (0.7, 0.0), obstacles, renew=blocked > 0)
        assert escape.routes == blocked + 1 and escape.blocked == blocked
        route = escape._route
        far = np.hypot(*(route - (1.45, 0.2)).T) > 0.35
        clearances.append(clearance_along(route[far], [wall]).min())
        escape.release_if_done(now + PATIENCE - 0.01, (1.5, 0.2), lambda: False)
        assert escape.active                        # moved only 0.05 m, not yet blocked
        now += PATIENCE
        escape.release_if_done(now, (1.5, 0.2), lambda: False)
        assert not escape.active and escape.blocked == blocked + 1
    assert all(c >= FREE + WIDEN * k - 1e-9 for k, c in enumerate(clearances))
    escape.engage(now, (1.5, 0.2), 0.0, (0.7, 0.0), obstacles, renew=True)
    assert escape.routes == MAX_WIDEN + 1 and escape.side != 0 and escape.blocked == 0


def test_bad_settings_are_refused():
    """Clearances, times, gains and the lookahead must be positive."""
    with pytest.raises(ValueError):
        RouteEscape(0.0)
    with pytest.raises(ValueError):
        RouteEscape(FREE, lookahead=0.0)
