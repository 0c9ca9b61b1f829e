"""The PyBullet world of a scenario: the one place for the simulator's physics.

``SimWorld(scenario)`` builds a DIRECT-mode world: a ground plane, every
obstacle as a vertical prism (one convex-mesh body per convex part, collision
margin 0 so distances are exact), and the robots.  An obstacle's bodies are
made when a closest-point query first comes within range of it (creating one
costs ~0.5 ms, and BARN's worlds have 260 cylinders of which a run passes a
fraction); a query never skips a body that could answer it, so this changes no
distance.  With the GUI they are all made at once, to be seen.  ``step()`` advances one
physics step of ``dt = 1 / physics_rate``; commands are held between
``set_command`` calls (zero-order hold).  A pop-up obstacle (``appear_at`` =
t_a > 0) gets its bodies at the first step with t >= t_a; until then it is in
no footprint list, clearance or collision, and ``obstacle_version`` counts
the appearances so a publisher can send the new set at once.  A moving obstacle
translates at a constant velocity, or along its ``trajectory``
(``ObstacleSpec``): each physics step moves its bodies (and, on ``ray_scene()``,
its copy for the lidars) to the step's time, and its footprint carries the
instantaneous velocity.

The robots are the plants of ``sim_bridge.plants`` (``PLANTS``, by robot type), the
obstacles ``sim_bridge.obstacle_bodies``; lidars see the world through ``ray_scene()``
(``sim_bridge.ray_scene``).
"""
import math

import numpy as np
import pybullet as pb
import pybullet_data

from polyc2bf_ros.core.models import crazyflie as cf
from sim_bridge.obstacle_bodies import Footprint, ObstacleBody
from sim_bridge.plants import CrazyfliePlant, PLANTS
from sim_bridge.ray_scene import RayScene

GRAVITY = cf.GRAVITY
# Distance below which getClosestPoints counts as a collision (contact-solver
# penetration and float noise are far below it).
COLLISION_TOLERANCE = 1e-3            # m
# getClosestPoints search distance [m]: farther reads as inf.  A query costs in proportion to
# the link pairs within range (an A1 pair has 169, ~130 us even when none is), so keep
# it to the range that matters for clearance metrics.
CLEARANCE_RANGE = 0.5
# First search distance beyond a pair's lower bound [m]; doubled until points are found.
SEARCH_STEP = 0.1
# While nothing moves, the obstacles near a robot are listed with this much more range and
# the list is kept until the robot has moved as far [m] (``SimWorld._near_obstacles``).
NEAR_MARGIN = 0.25


class SimWorld:
    """A scenario's PyBullet world; call ``close()`` (or use ``with``) when done."""

    def __init__(self, scenario, gui=False):
        """Connect (DIRECT, or GUI), then build ground, obstacles and robots."""
        self.scenario = scenario
        self.dt = 1.0 / scenario.physics_rate
        self.steps = 0
        self._gui = gui
        self._synced_step = 0
        self._states = {}
        self._rays = None  # the lidars' RayScene, made by ray_scene()
        self._client = pb.connect(pb.GUI if gui else pb.DIRECT)
        client = self._client
        pb.setAdditionalSearchPath(pybullet_data.getDataPath(), physicsClientId=client)
        pb.setGravity(0.0, 0.0, -GRAVITY, physicsClientId=client)
        pb.setTimeStep(self.dt, physicsClientId=client)
        pb.setPhysicsEngineParameter(deterministicOverlappingPairs=1, physicsClientId=client)
        ground = pb.loadURDF('plane.urdf', physicsClientId=client)
        self._obstacles = [ObstacleBody(spec, index, client, lazy=not gui)
                           for index, spec in enumerate(scenario.all_obstacles())]
        self._present = np.array([o.present for o in self._obstacles], dtype=bool)
        self._hidden = sorted((o for o in self._obstacles if not o.present),
                              key=lambda o: o.spec.appear_at)
        self.obstacle_version = 0
        self._moving = [o for o in self._obstacles if o.moving and o.present]
        self._robots = {spec.name: PLANTS[spec.type](spec, client, ground)
                        for spec in scenario.robots}
        self._plants = list(self._robots.values())
        # Unicycle plants and obstacles are placed by resets, so a world without a
        # Bullet-integrated plant skips stepSimulation (see step()).
        self._bullet_steps = any(p.BULLET_STEPS for p in self._plants)
        for index, plant in enumerate(self._plants):
            plant.index = index
        self._lower = np.array([o.lower for o in self._obstacles]).reshape(-1, 2)
        self._upper = np.array([o.upper for o in self._obstacles]).reshape(-1, 2)
        self._offsets = np.zeros_like(self._lower)
        self._centres_step, self._footprints_step = -1, -1
        self._centres, self._footprints, self._pairs = {}, {}, {}
        self._near = {}  # (robot, search distance) -> listed obstacles (_near_obstacles)
        self._velocities = np.array([o.spec.velocity for o in self._obstacles]).reshape(-1, 2)
        self._appear_at = np.array([o.spec.appear_at for o in self._obstacles]).reshape(-1, 1)
        # Obstacles on a trajectory: their rows of _offsets come from it (here: t = 0).
        self._trajectories = [(index, o) for index, o in enumerate(self._obstacles)
                              if o.trajectory is not None]
        for index, obstacle in self._trajectories:
            self._offsets[index] = obstacle.offset(0.0)

    @property
    def time(self):
        """Return the simulated time [s] = steps * dt."""
        return self.steps * self.dt

    @property
    def robot_names(self):
        """Return the robots' names in scenario order."""
        return tuple(self._robots)

    def robot_spec(self, robot):
        """Return the scenario's RobotSpec of ``robot``."""
        return self._robots[robot].spec

    def set_command(self, robot, cmd, kind=None):
        """Hold ``cmd`` for ``robot`` until the next call.

        Quadruped, diff drive: kind 'velocity' (default) [v, omega] or 'acceleration'
        [a, alpha].
        Crazyflie: kind 'thrusts' (default) f (4,) [N] or 'wrench' [T, tau_x, tau_y, tau_z].
        Raises ValueError for an unknown kind or a wrongly sized or non-finite command.
        """
        plant = self._robots[robot]
        kinds = plant.COMMAND_KINDS
        kind = kind or kinds[0]
        if kind not in kinds:
            raise ValueError(f'{robot} ({plant.spec.type}) takes commands of kind '
                             f'{" or ".join(kinds)}, not {kind!r}')
        plant.set_command(cmd, kind)

    def set_actuator_tau(self, robot, tau):
        """Give ``robot``'s plant a first-order response of time constant ``tau`` [s] >= 0.

        Quadruped, diff drive: the velocity loop; Crazyflie: the rotors
        (``sim_bridge.actuation``).
        """
        if not (math.isfinite(tau) and tau >= 0.0):
            raise ValueError(f'actuator_tau must be a finite number >= 0, got {tau!r}')
        plant = self._robots[robot]
        plant.actuator_tau, plant.dt = float(tau), self.dt

    def step(self):
        """Advance one physics step: forces, Bullet step, plants, pop-ups, moving obstacles.

        The Bullet step runs only when a Crazyflie flies: for quadrupeds and
        obstacles alone it would integrate nothing (~0.1 ms per step for one
        A1 and 50 obstacles; closest points agree with and without it to 1e-14 m).
        """
        for plant in self._plants:
            plant.before_physics()
        if self._bullet_steps:
            pb.stepSimulation(physicsClientId=self._client)
        self.steps += 1
        for plant in self._plants:
            plant.after_physics(self.dt)
        if self._gui:
            self._sync_bodies()
        if self._hidden:
            self._reveal()
        if self._moving:
            time = self.time
            for obstacle in self._moving:
                obstacle.place(time)
            np.multiply(self._velocities, time - self._appear_at, out=self._offsets)
            for index, obstacle in self._trajectories:
                self._offsets[index] = obstacle.offset(time)

    def _reveal(self):
        """Create the bodies of pop-up obstacles whose ``appear_at`` has come."""
        time = self.time
        while self._hidden and self._hidden[0].spec.appear_at <= time + 1e-9:
            obstacle = self._hidden.pop(0)
            obstacle.appear(time)
            self._present[obstacle.footprint.index] = True
            if obstacle.moving:
                self._moving.append(obstacle)
                self._moving.sort(key=lambda o: o.footprint.index)
            self.obstacle_version += 1

    def robot_state(self, robot):
        """Return ``robot``'s state in the core model's layout (unicycle or quadrotor).

        Read from the plant once per physics step (a Crazyflie's costs four
        PyBullet queries), a copy per call.
        """
        step, state = self._states.get(robot, (None, None))
        if step != self.steps:
            state = self._robots[robot].robot_state()
            self._states[robot] = (self.steps, state)
        return state.copy()

    def body_twist(self, robot):
        """Return ``robot``'s twist in its body frame: (vx, vy, vz, wx, wy, wz)."""
        return self._robots[robot].body_twist()

    def _sync_bodies(self):
        """Move kinematic robot bodies to their plants' poses, once per physics step."""
        if self._synced_step != self.steps:
            self._synced_step = self.steps
            for plant in self._plants:
                plant.sync()

    def robot_pose(self, robot):
        """Return PyBullet's base position (3,) and quaternion [x, y, z, w] of ``robot``."""
        self._sync_bodies()
        position, quaternion = pb.getBasePositionAndOrientation(
            self._robots[robot].body, physicsClientId=self._client)
        return np.array(position), np.array(quaternion)

    def ray_scene(self):
        """Return (PyBullet client, {robot: its proxy body}) of what lidars see, synced to now.

        The scene (``RayScene``) is made on the first call and moved to the current time
        on every call; the world's own client, bodies and metrics are untouched by it.
        """
        if self._rays is None:
            self._rays = RayScene(self._obstacles, self._plants)
        self._rays.sync(self.time)
        return self._rays.client, self._rays.proxies

    def _robot_centres(self):
        """Return each robot's base [x, y], computed once per physics step."""
        if self._centres_step != self.steps:
            self._centres_step = self.steps
            self._pairs.clear()
            self._centres = {name: plant.centre() for name, plant in self._robots.items()}
        return self._centres

    def _robot_footprints(self):
        """Return each robot's footprint circle, computed once per physics step."""
        if self._footprints_step != self.steps:
            self._footprints_step = self.steps
            self._footprints = {}
            for name, plant in self._robots.items():
                position, velocity, z_min, z_max = plant.extent()
                self._footprints[name] = Footprint(name, position[:2] + plant.circle, z_min,
                                                   z_max, velocity, plant.index, robot=True)
        return self._footprints

    def joint_positions(self, robot):
        """Return {joint name: angle [rad]} of the robot's joints (none for a Crazyflie)."""
        body = self._robots[robot].body
        count = pb.getNumJoints(body, physicsClientId=self._client)
        names = [pb.getJointInfo(body, j, physicsClientId=self._client)[1].decode()
                 for j in range(count)]
        states = pb.getJointStates(body, range(count), physicsClientId=self._client) or ()
        return {name: state[0] for name, state in zip(names, states)}

    def obstacle_footprints(self, robot=None, moving_only=False):
        """Return each present obstacle's current Footprint, then every robot but ``robot``.

        Obstacles in scenario order, pop-ups only once they have appeared
        (``moving_only``: only the moving ones).  Another robot is the circle of
        its scenario ``radius`` around its base.
        """
        time = self.time
        footprints = self._robot_footprints()
        obstacles = self._moving if moving_only else (o for o in self._obstacles if o.present)
        return ([o.footprint_at(time) for o in obstacles]
                + [f for name, f in footprints.items() if name != robot])

    def clearances(self, robot, max_distance=CLEARANCE_RANGE):
        """Return closest-point distances [m] from ``robot`` to each obstacle, then other robots.

        Same order as ``obstacle_footprints(robot)``; negative means penetration,
        inf means farther than ``max_distance``.  Obstacles whose bounding box, and
        robots whose reach, is farther than ``max_distance`` from this robot's reach
        are skipped unqueried; a robot pair is queried once per physics step.
        Robot bodies are moved to their plants' poses only when a query runs.
        """
        plant = self._robots[robot]
        obstacles = np.full(len(self._obstacles), np.inf)
        for index, bound in zip(*self._near_obstacles(robot, max_distance)):
            obstacles[index] = self._obstacle_distance(plant, index, bound, max_distance)
        return np.concatenate([obstacles[self._present],
                               self._robot_distances(robot, max_distance)])

    def min_clearance(self, robot, max_distance=CLEARANCE_RANGE):
        """Return ``min(clearances(robot, max_distance))`` (inf if empty), with fewer queries.

        For a Crazyflie the floor counts too (``floor_gap``): touching it is a collision.

        Obstacles are queried in the order of their lower bounds, and none once the
        bound exceeds the best distance found: no such obstacle can be closer.
        """
        plant = self._robots[robot]
        best = min(self._robot_distances(robot, max_distance), default=math.inf)
        if isinstance(plant, CrazyfliePlant):  # a flying body: the floor is an obstacle too
            gap = plant.floor_gap()
            if gap < max_distance:
                best = min(best, gap)
        for bound, index in sorted(zip(*self._near_obstacles(robot, max_distance)[::-1])):
            reach = min(best, max_distance)
            if bound > reach:
                break
            best = min(best, self._obstacle_distance(plant, index, bound, reach))
        return best

    def _near_obstacles(self, robot, max_distance):
        """Return the present obstacles with lower bound <= ``max_distance``: indices, bounds.

        Bound on the distance to ``robot``: the gap between the obstacle's bounding box and
        the robot's base, minus the robot's reach.  While nothing moves, the obstacles with
        bound <= max_distance + NEAR_MARGIN are listed once per robot, and that list serves
        until the robot's base has moved NEAR_MARGIN: a bound falls by at most the distance
        moved, so no obstacle outside the list can have come within range.
        """
        position = self._robot_centres()[robot]
        x, y = position.tolist()
        reach = self._robots[robot].reach
        key = (robot, max_distance)
        listed = self._near.get(key)
        if (listed is None or self._moving or listed[0] != self.obstacle_version
                or math.hypot(listed[1][0] - x, listed[1][1] - y) > NEAR_MARGIN):
            margin = 0.0 if self._moving else NEAR_MARGIN
            lower, upper = self._lower + self._offsets, self._upper + self._offsets
            gaps = np.maximum(np.maximum(lower - position, position - upper), 0.0)
            index = np.flatnonzero((np.hypot(gaps[:, 0], gaps[:, 1]) - reach
                                    <= max_distance + margin) & self._present)
            boxes = np.hstack([index[:, None], lower[index], upper[index]]).tolist()
            listed = self._near[key] = (self.obstacle_version, (x, y), boxes)
        indices, bounds = [], []
        for index, low_x, low_y, high_x, high_y in listed[2]:
            bound = math.hypot(max(low_x - x, x - high_x, 0.0),
                               max(low_y - y, y - high_y, 0.0)) - reach
            if bound <= max_distance:
                indices.append(int(index))
                bounds.append(bound)
        return indices, bounds

    def _obstacle_distance(self, plant, index, lower_bound, max_distance):
        """Return the distance from ``plant``'s body to obstacle ``index`` (``_distance``)."""
        return min(self._distance(plant.body, body, lower_bound, max_distance, plant.links == 1)
                   for body in self._obstacles[index].bodies_at(self.time))

    def _robot_distances(self, robot, max_distance):
        """Return the distances to every other robot, in order (inf beyond ``max_distance``).

        A pair is queried once per physics step and search distance.
        """
        plant = self._robots[robot]
        centres = self._robot_centres()
        x, y = centres[robot]
        distances = []
        for name, other in self._robots.items():
            if name == robot:
                continue
            other_x, other_y = centres[name]
            bound = math.hypot(other_x - x, other_y - y) - plant.reach - other.reach
            distance = np.inf
            if bound <= max_distance:
                key = (min(plant.body, other.body), max(plant.body, other.body), max_distance)
                if key not in self._pairs:
                    self._pairs[key] = self._distance(plant.body, other.body, bound,
                                                      max_distance,
                                                      plant.links == other.links == 1)
                distance = self._pairs[key]
            distances.append(distance)
        return distances

    def _distance(self, body_a, body_b, lower_bound, max_distance, single_links=False):
        """Return the smallest getClosestPoints distance between two bodies, inf if none.

        Bullet returns every link pair within the search distance, and its cost
        grows with their number (two overlapping A1s: 31 pairs in contact at
        distance 0, ~0.26 ms; 480 within 0.5 m, ~1.5 ms), so the search starts
        at 0 (contact) when the pair's lower bound allows contact, else
        SEARCH_STEP beyond the bound, and doubles until some pair is found; the
        minimum over a non-empty answer is exact.  Two ``single_links`` bodies
        (a disc and an obstacle) are one pair: one query at the search distance.
        """
        self._sync_bodies()
        if single_links:
            points = pb.getClosestPoints(body_a, body_b, max(max_distance, 0.0),
                                         physicsClientId=self._client)
            return min((point[8] for point in points), default=np.inf)
        threshold = min(lower_bound + SEARCH_STEP, max_distance) if lower_bound > 0.0 else 0.0
        while True:
            points = pb.getClosestPoints(body_a, body_b, threshold, physicsClientId=self._client)
            if points:
                return min(point[8] for point in points)
            if threshold >= max_distance:
                return np.inf
            threshold = min(max(2.0 * threshold, SEARCH_STEP), max_distance)

    def collided(self, robot):
        """Return True when ``robot`` penetrates an obstacle or robot by > COLLISION_TOLERANCE."""
        return bool(np.min(self.clearances(robot, max_distance=0.0), initial=np.inf)
                    < -COLLISION_TOLERANCE)

    def close(self):
        """Disconnect from PyBullet (and the ray scene's client); safe to call twice."""
        if self._rays is not None:
            self._rays.close()
            self._rays = None
        if self._client is not None:
            pb.disconnect(physicsClientId=self._client)
            self._client = None

    def __enter__(self):
        """Return the world for a ``with`` block."""
        return self

    def __exit__(self, *exc):
        """Close the world."""
        self.close()
