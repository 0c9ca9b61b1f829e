"""Deadlock resolution by a route: steer the nominal along a grid route past the blockage.

Circulation (``core.liveness.circulation``) follows the boundary of the one obstacle part holding
the robot.  In clutter that is often the wrong way: the side it latches ends in a gap
narrower than the guard disc, or in a pocket of several parts, and a reactive rule has no
way to know.  The filter holds every obstacle it guards against, so when a deadlock is
reported this resolution looks at all of them once and plans where to go instead.

Intent.  The nominal [v, omega] held at the deadlock points where its law wants to go:
the direction d = R(clip(omega t_i, +-pi/2)) (cos theta, sin theta), t_i = 1 s (a
go-to-goal law turns at omega = k e towards its goal, so d leans the way it turns).

Grid.  A square window of side ``window`` about the reference point p, cells of side
``cell``.  Each cell centre q gets its clearance c(q) = min over parts n of the signed
distance from q to footprint n (negative inside; ``grid_clearance``).  A cell is free when
c >= c_min = guard radius + braking margin (+ 2 cm), the distance the filter's braking
check keeps (``core.barrier.braking_check``).  A robot guarded by its footprint polygon
(``barrier.footprint_cone``) is planned as the disc of half its least width
(``ObstacleGeometry.passage_radius``): the route's gaps are those the body passes aligned
with them.  That is the approximation's price: where the route turns near a part the
body's corners reach farther (up to its covering radius), the filter holds them off, and
the robot may stand there until the route is planned again, wider.  The held robot
stands closer than c_min, so cells within ``START_CELLS`` of p need only
c >= min(c_min, c(p)): no closer to any part than p is.  A step that loses clearance
there points into the cone of the part it nears, which the filter refuses from the
boundary (measured: BARN robots turned onto such a first leg and stood).

Route.  Dijkstra over the 8-connected free cells from p's cell (``route_search``), each
step costing its length times 1 + w max(0, c_pref - c) / (c_pref - c_min) with
c_pref = c_min + ``preferred_margin``: a route keeps away from the parts where it can.  It
ends at the first cell popped whose offset from p along d is at least ``ahead``, whose
clearance is at least c_min + ``preferred_margin`` / 2, and (``run`` > 0, the parameter
``route_clear_run``) from which a straight run of ``run`` along d keeps to free cells
(``clear_runs``; past the window counts as free, and so does space no laser saw): the
nearest free place the way the nominal wants, past whatever holds the robot, from which it
can drive on.  That includes backing out of a pocket.  Ended ``ahead`` along d with the next
row of parts just beyond, the nominal drives on into that row and is held again (measured
on BARN from markers, a Jackal at 2 m/s, go-to-goal: the first report at the entry of the
post field, the route's end 3 m on still inside it, the next report 0.5-1.6 m past the
end).  When no cell in the window has such a run, the route ends at the first cell popped
that meets the rest.

Unseen.  From a laser the obstacle set holds only what its beams lit: a post in the
shadow of another, or in the laser's blind sector, is not in it, and a route planned as if
that space were free runs into it, stands, and is planned again (measured on BARN world
181, a Jackal from its 270-degree laser, go-to-goal: 14 routes in 100 s, nearly every one
after the first through posts no scan had shown; timeout).  So with the ``ScanView`` of each
laser's newest scan (``ObstacleSnapshot.views``) a step into a cell that no beam reached
(``ScanView.unseen``: outside the beams' span or range, or behind a nearer return) costs
1 + ``UNSEEN_WEIGHT`` times as much, except within ``SEEN_AROUND`` of the robot, which
stands there (``unseen_cells``): of two ways past a blockage the route takes the one the
laser saw unless the unseen one is much shorter, and past what was seen it still goes on.
Obstacles from markers come with no view, and everything counts as seen.

Following.  Per step the target is the route point ``lookahead`` (arc length) beyond the
point nearest the reference point (searched forward from the last one), and, for a
unicycle as circulation does, with e = wrap(atan2(target - p) - theta)::

    omega* = clip(k_theta e, +-omega_max),    v* = v_n max(0, cos e)

v_n as in circulation (the larger of the nominal's |v| now and at the report).  The safety
filter filters that command like any other: no CBF row is dropped or relaxed.

Replanning.  A route planned from a laser runs through space its beams had not lit, and
the posts there show up only as the robot nears them.  Followed on, such a route leads into
them: the robot is held, creeps, and is reported again after ``deadlock_time``, before a
new plan (measured on BARN from the laser, a Jackal at 2 m/s, go-to-goal: in 42 of 200
worlds one report from markers was two or three from the laser, and those worlds held
77 % of the metric the laser lost against markers; traced in worlds 158 and 160, the first
route passed 0.10-0.13 m from posts no beam had lit at the plan, 0.87-0.98 m from
any part the filter knew, and the second report came there).  So while a route is
followed, each new obstacle set is checked against it (``revise``): when a standing part
(no velocity: a moving one crosses and goes on) now comes ``REPLAN_LOSS`` nearer some
route point ahead than the plan allowed, min(c at the plan, c_min), the route is planned
again from where the robot is, the way the nominal points then, without backing (the robot
is moving, not nose-in).  When no new route is found the old one is kept: if the robot is
held on it, the next report plans as usual.  From markers every post is known at the
first plan and nothing changes.  (With it, that go-to-goal metric from the laser rose
0.4165 -> 0.4369 and its reports 266 -> 223; bench/README.md.)

Release.  The nominal takes over again at the route's end (within ``lookahead`` of it) or
after max(``max_time``, 3 L / v_n) s for a route of length L.  A route the filter holds the
robot on (the cone of a part it passes close by covers the way to its next point: the
cones forbid more than the clearance does) is *blocked* once the robot has not moved
0.1 m in ``PATIENCE`` s; the deadlock still held, the next plan keeps ``WIDEN`` more
clearance, up to ``MAX_WIDEN`` times in a row, then circulation takes over.  A second
report while following (held again after moving: a part moved, or the route was too
tight) plans a new route from where the robot stands; so does a deadlock that outlasts a
route.  When no route exists in the window (every way blocked, or none ``ahead`` far
enough), the resolution falls back to circulation, and a deadlock that outlasts that plans
again only ``max_time`` later (not on every held step).  A nominal stop passes unchanged.

Backing.  A robot guarded by its footprint polygon (``barrier.footprint_cone``) that drove
nose-in up to a part cannot always turn in place there: its corners sweep a circle of its
covering radius r.  Its route starts ``backing`` = r - (half its least width) + 2 cm behind
it along the heading, so the route's first leg backs it out to where it can turn: while
on that leg, a route point behind the robot (cos e < 0) is driven to in reverse at no more
than ``BACKING_SPEED``, v* = -min(v_n, v_b) max(0, cos e'), omega* = clip(k_theta e',
+-omega_max), e' = wrap(e - pi); past it the rule above (turn, then forward).  Reversing
no farther keeps a robot whose laser faces forward from driving blind: behind it the
filter knows only what the laser saw before (``obstacles.scan_memory``).  A disc robot
turns in place anywhere, and keeps ``backing`` 0.

Holonomic bases (``point_mass_2d``, body-frame commands [vx, vy] at the odometry yaw psi)
take d = Rz(psi) [vx, vy] / |[vx, vy]| and follow with the velocity v_n (target - p) /
|target - p|, turned back into the body frame; v_n = |[vx, vy]|.  Without a route they
keep their nominal (there is no circulation for them).
"""
import math

import numpy as np

from polyc2bf_ros.core.barrier.cones import PlanarPolygons
from polyc2bf_ros.core.geometry.polygons import PolygonBatch
from polyc2bf_ros.core.kernels.route import grid_clearance, route_search
from polyc2bf_ros.core.liveness.circulation import Circulation, steer_towards

BACKING_SPEED = 0.25  # m/s: a box backs out of its nose-in stand no faster (its laser may
#                       face forward only)
PATIENCE = 3.0   # s: a route the robot has not moved 0.1 m along in this long is blocked
#                  (longer than a half turn in place at 1.5 rad/s)
WIDEN = 0.1      # m: each blocked route in a row plans the next this much wider ...
MAX_WIDEN = 2    # ... this many times; one more, and circulation takes over
INTENT_TIME = 1.0  # s: d leans by omega * INTENT_TIME, at most 90 degrees
UNSEEN_WEIGHT = 2.0  # a step into a cell no laser saw costs 1 + this times more ("Unseen";
#                     BARN, Jackal from its laser, 40 worlds: metric 0.404 / 0.416 / 0.412
#                     for 1 / 2 / 5)
SEEN_AROUND = 0.5    # m: the cells this near the robot count as seen (it stands there)
REPLAN_LOSS = 0.05   # m: a standing part this much nearer a route point than the plan
#                     allowed blocks the route ahead ("Replanning"; a lit post cuts 0.1 m+)


def plan_route(obstacles, position, direction, free, window=10.0, cell=0.1, ahead=3.0,
               preferred_margin=0.4, weight=4.0, views=(), run=0.0):
    """Return the route (K, 2) from ``position`` ``ahead`` m along ``direction``, or None.

    ``obstacles``: an ``ObstacleSet``; ``free``: the clearance c_min a cell needs; the
    start band needs min(c_min, clearance at ``position``) (module docstring).  ``views``:
    the ``ScanView`` of each laser's newest scan, whose unseen cells cost more ("Unseen");
    ``run`` [m]: the straight run along ``direction`` the end should have free (0: any end).
    """
    count = int(round(window / cell)) | 1
    half = (count // 2) * cell
    x0, y0 = float(position[0]) - half, float(position[1]) - half
    clearance = np.empty((count, count))
    polygons = PlanarPolygons.from_batch(obstacles.footprints)
    preferred = free + preferred_margin
    grid_clearance(polygons.x, polygons.y, polygons.edge_x, polygons.edge_y,
                   polygons.inv_sq, np.ascontiguousarray(polygons.counts, dtype=np.int64),
                   x0, y0, cell, preferred + cell, clearance)
    cells = count * count
    parent = np.empty(cells, dtype=np.int64)
    scratch = np.empty(9 * cells)
    heap = np.empty(8 * cells, dtype=np.int64)
    centre = count // 2
    unseen = unseen_cells(views, x0, y0, cell, count, position)
    run_clear = clear_runs(clearance >= free, direction, round(run / cell))
    end = route_search(clearance, unseen, run_clear, centre, centre, float(direction[0]),
                       float(direction[1]), ahead / cell, free,
                       min(free, clearance[centre, centre]), preferred, weight,
                       UNSEEN_WEIGHT, parent, scratch, heap)
    if end < 0:
        return None
    indices = [int(end)]
    while parent[indices[-1]] >= 0:
        indices.append(int(parent[indices[-1]]))
    indices = np.array(indices[::-1])
    route = np.column_stack((x0 + (indices % count) * cell, y0 + (indices // count) * cell))
    route[0] = position
    return route


def route_clearances(obstacles, points, cutoff):
    """Return (K,) min(``cutoff``, signed distance of each point to the set's standing parts).

    Standing: a part with no planar velocity (``ObstacleSet.velocities``).  The grid
    kernel (``grid_clearance``) measures each point as a one-cell grid.
    """
    standing = ~np.any(obstacles.velocities[:, :2] != 0.0, axis=1)
    footprints = obstacles.footprints
    polygons = PlanarPolygons.from_batch(
        PolygonBatch(footprints.vertices[standing], footprints.counts[standing]))
    counts = np.ascontiguousarray(polygons.counts, dtype=np.int64)
    cell, clearances = np.empty((1, 1)), np.empty(len(points))
    for k, (x, y) in enumerate(np.asarray(points, dtype=float)):
        grid_clearance(polygons.x, polygons.y, polygons.edge_x, polygons.edge_y,
                       polygons.inv_sq, counts, float(x), float(y), 1.0, cutoff, cell)
        clearances[k] = cell[0, 0]
    return clearances


def clear_runs(free, direction, steps):
    """Return (count, count) 1.0 where a run of ``steps`` cells along ``direction`` is free.

    ``free``: (count, count) bool, the cells a route may take.  The run samples one cell per
    step along the unit ``direction`` (rounded to the nearest cell); samples past the window
    count as free (the plan knows nothing there).
    """
    count = free.shape[0]
    rows, columns = np.indices(free.shape)
    clear = np.ones(free.shape, dtype=bool)
    for k in range(1, steps + 1):
        i = rows + int(round(k * float(direction[1])))
        j = columns + int(round(k * float(direction[0])))
        inside = (i >= 0) & (i < count) & (j >= 0) & (j < count)
        clear[inside] &= free[i[inside], j[inside]]
    return clear.astype(float)


def unseen_cells(views, x0, y0, cell, count, position):
    """Return (count, count) 1.0 where no laser's newest scan saw the cell centre, else 0.

    Cell (i, j) has its centre at (x0 + j cell, y0 + i cell).  A centre is seen when some
    ``views`` beam reached it, less a cell (``ScanView.unseen``: within the beams' span and
    range, and not behind a nearer return); so is every cell within ``SEEN_AROUND`` of
    ``position``, where the robot stands.  No views (obstacles from markers): all zeros.
    """
    unseen = np.zeros((count, count))
    if not views:
        return unseen
    axis = np.arange(count) * cell
    centres = np.column_stack((np.tile(x0 + axis, count), np.repeat(y0 + axis, count)))
    hidden = np.ones(len(centres), dtype=bool)
    for view in views:
        ranges, after = view.bearings(centres)
        hidden &= view.unseen(ranges, after, cell)
    near = np.hypot(centres[:, 0] - float(position[0]),
                    centres[:, 1] - float(position[1])) <= SEEN_AROUND
    unseen.reshape(-1)[hidden & ~near] = 1.0
    return unseen


class RouteEscape:
    """The rule of the module docstring; ``ControlDecision`` drives it like ``Circulation``."""

    def __init__(self, free_clearance, holonomic=False, max_time=10.0, turn_gain=2.0,
                 max_turn_rate=1.5, lookahead=0.25, backing=0.0, **route):
        """Follow routes keeping ``free_clearance`` [m]; ``route``: ``plan_route``'s options.

        ``holonomic``: commands are body-frame velocities [vx, vy] (``point_mass_2d``), not
        unicycle [v, omega]; there is no circulation to fall back on.  ``backing`` [m]: a
        unicycle first backs this far along its heading, and drives in reverse to route
        points behind it (module docstring, "Backing").
        """
        if not (free_clearance > 0.0 and max_time > 0.0 and turn_gain > 0.0
                and max_turn_rate > 0.0 and lookahead > 0.0):
            raise ValueError('escape route: free_clearance, max_time, turn_gain, '
                             'max_turn_rate and lookahead must be positive')
        self.free_clearance = float(free_clearance)
        self.holonomic = bool(holonomic)
        self.backing = 0.0 if self.holonomic else float(backing)
        self.max_time, self.lookahead = float(max_time), float(lookahead)
        self.turn_gain, self.max_turn_rate = float(turn_gain), float(max_turn_rate)
        self.route_options = route
        self.fallback = Circulation(max_time=max_time, turn_gain=turn_gain,
                                    max_turn_rate=max_turn_rate)
        self.engagements = 0   # routes planned (or circulations started without one)
        self.routes = 0        # of those, routes found
        self.replans = 0       # routes planned again while followed ("Replanning")
        self._route = None     # (K, 2) route points
        self._allowed = None   # (K,) min(clearance at the plan, c_min) of each point
        self._checked = None   # the obstacle set the route was last checked against
        self._arc = None       # (K,) arc length at each point
        self._progress = 0     # index of the route point nearest the robot
        self._since = math.nan
        self._limit = math.inf
        self._speed = 0.0
        self._failed = -math.inf  # when planning last found no route
        self.blocked = 0          # routes in a row the filter held the robot on
        self._anchor, self._moved = None, math.nan

    @property
    def active(self):
        """Return True while following a route or circulating for want of one."""
        return self._route is not None or self.fallback.active

    @property
    def mode(self):
        """Return what steers the nominal now: 'route', 'circulate' (fallback) or 'none'."""
        return 'route' if self._route is not None else self.fallback.mode

    @property
    def side(self):
        """Return the fallback circulation's side (0 while following a route)."""
        return self.fallback.side

    def observe(self, info):
        """Pass the step's filter info to the fallback circulation."""
        self.fallback.observe(info)

    def engage(self, now, position, yaw, nominal, obstacles=None, renew=False, views=()):
        """Plan a route from ``position`` the way ``nominal`` points (module docstring).

        ``renew`` (the deadlock outlasted the last resolution, asked every held step) plans
        at most once per ``max_time`` after a plan that found no route.  ``views``: the
        lasers' newest ``ScanView`` each (``plan_route``).
        """
        if renew and now - self._failed < self.max_time:
            return
        if self.holonomic and not any(nominal):
            return
        self._speed = max(self._speed_of(nominal), self._speed if self.active or renew else 0.0)
        route = None
        if obstacles is not None and len(obstacles) and self.blocked <= MAX_WIDEN:
            route = self._plan(position, yaw, nominal, obstacles, views, self.backing)
        self.engagements += 1
        if route is None:
            self.blocked = 0
            self._route, self._failed = None, now
            if not self.holonomic:
                self.fallback.engage(now, position, yaw, nominal, renew=renew)
            return
        self.fallback.side = 0
        self.routes += 1
        self._follow(now, position, route, obstacles)

    def revise(self, now, position, yaw, nominal, obstacles, views=()):
        """Plan the route again when a standing part now lies on it ahead ("Replanning").

        Called with every step's obstacle set while following a route; a set already
        checked is not checked again.  Return True when a new route replaced the old one.
        """
        if self._route is None or obstacles is self._checked or not len(obstacles):
            return False
        self._checked = obstacles
        ahead = slice(self._progress, None)
        clearances = route_clearances(obstacles, self._route[ahead], self.free_clearance)
        if not np.any(clearances < self._allowed[ahead] - REPLAN_LOSS):
            return False
        if self.holonomic and not any(nominal):
            return False
        route = self._plan(position, yaw, nominal, obstacles, views, 0.0)
        if route is None:
            return False
        self.replans += 1
        self._follow(now, position, route, obstacles)
        return True

    def _plan(self, position, yaw, nominal, obstacles, views, backing):
        """Return a route from ``position`` (``backing`` m back first) the way ``nominal`` points.

        None when ``plan_route`` finds none.
        """
        if self.holonomic:
            bearing = math.atan2(float(nominal[1]), float(nominal[0])) + yaw
        else:
            bearing = yaw + min(max(float(nominal[1]) * INTENT_TIME, -0.5 * math.pi),
                                0.5 * math.pi)
        start = np.asarray(position, dtype=float)
        backed = start - backing * np.array([math.cos(yaw), math.sin(yaw)])
        route = plan_route(obstacles, backed, (math.cos(bearing), math.sin(bearing)),
                           self.free_clearance + WIDEN * self.blocked, views=views,
                           **self.route_options)
        if route is not None and backing > 0.0:
            route = np.vstack((start, route))
        return route

    def _follow(self, now, position, route, obstacles):
        """Start following ``route``, planned among ``obstacles``."""
        self._route, self._progress, self._since = route, 0, now
        self._allowed = route_clearances(obstacles, route, self.free_clearance)
        self._checked = obstacles
        self._anchor, self._moved = np.array(position, dtype=float), now
        self._arc = np.concatenate(([0.0], np.cumsum(np.hypot(*np.diff(route, axis=0).T))))
        speed = max(self._speed, 1e-3)
        self._limit = max(self.max_time, 3.0 * float(self._arc[-1]) / speed)

    def release_if_done(self, now, position, passes):
        """End the route at its end, after its time limit or blocked; the fallback by its rule.

        Blocked: the reference point stayed within 0.1 m for ``PATIENCE`` s; the next plan
        (the deadlock still held) keeps ``WIDEN`` more clearance per blocked route in a row.
        """
        if self._route is None:
            self.fallback.release_if_done(now, position, passes)
            return
        self._advance(position)
        position = np.asarray(position, dtype=float)
        if np.linalg.norm(position - self._anchor) > 0.1:
            self._anchor, self._moved = position, now
        if now - self._moved >= PATIENCE:
            self._route, self.blocked = None, self.blocked + 1
        elif (now - self._since >= self._limit
                or self._arc[-1] - self._arc[self._progress] <= self.lookahead):
            self._route, self.blocked = None, 0

    def probe(self, nominal):
        """Return the fallback's probe of ``nominal`` (``Circulation.probe``)."""
        return self.fallback.probe(nominal)

    def command(self, yaw, nominal, position=None):
        """Return the command [v, omega] to ask the filter for (module docstring)."""
        if self._route is None:
            return self.fallback.command(yaw, nominal)
        if not any(nominal) or position is None:
            return nominal
        self._advance(position)
        target_arc = self._arc[self._progress] + self.lookahead
        target = self._route[min(int(np.searchsorted(self._arc, target_arc)),
                                 len(self._route) - 1)]
        bearing = math.atan2(target[1] - position[1], target[0] - position[0])
        speed = max(self._speed_of(nominal), self._speed)
        if self.holonomic:   # the velocity towards the target, in the body frame
            return speed * np.array([math.cos(bearing - yaw), math.sin(bearing - yaw)])
        if (self.backing > 0.0 and self._arc[self._progress] < self.backing
                and math.cos(bearing - yaw) < 0.0):   # backing out: in reverse, slowly
            v, omega = steer_towards(bearing + math.pi, yaw, min(speed, BACKING_SPEED),
                                     self.turn_gain, self.max_turn_rate)
            return np.array([-v, omega])
        return steer_towards(bearing, yaw, speed, self.turn_gain, self.max_turn_rate)

    def _speed_of(self, nominal):
        """Return the nominal's speed: |[vx, vy]| (holonomic) or |v| (unicycle)."""
        if self.holonomic:
            return math.hypot(float(nominal[0]), float(nominal[1]))
        return abs(float(nominal[0]))

    def _advance(self, position):
        """Move the progress index to the nearest route point within reach ahead."""
        reach = self._arc[self._progress] + 2.0 * self.lookahead
        last = int(np.searchsorted(self._arc, reach, side='right'))
        window = self._route[self._progress:max(last, self._progress + 1)]
        offsets = window - np.asarray(position, dtype=float)
        self._progress += int(np.argmin(np.einsum('ij,ij->i', offsets, offsets)))
