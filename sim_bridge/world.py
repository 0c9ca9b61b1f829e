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

Quadruped (Unitree A1, ``pybullet_data/a1/a1.urdf``, a dynamic body) and
diff-drive base (an upright PyBullet cylinder of the scenario's ``radius`` and
``DIFF_DRIVE_HEIGHT``, a dynamic body) are the paper's acceleration-controlled
unicycle: both are the one plant below, driven by ``cmd_vel`` [v, omega].  Its
plant state [x, y, theta, v, omega] is integrated here, per physics step dt::

    velocity command: a = clip((v_cmd - v) / dt, +-a_max)   (reach v_cmd at a_max)
    acceleration command: a = clip(a_cmd, +-a_max)
    v' = clip(v + a dt, +-v_max)   (same for omega with alpha_max, omega_max)
    theta' = theta + (omega + omega') dt / 2
    [x, y]' = [x, y] + (v + v') dt / 2 [cos, sin](theta + (omega + omega') dt / 4)

and the Bullet base is reset to that pose at standing height, upright
(roll = pitch = 0), before anything reads it (closest points,
``robot_pose``; every step with the GUI): a reset costs ~20 us per A1.  The
body (mass > 0) is kept asleep with wake-up disabled (and an A1's joint motors
off), so Bullet never integrates it: gravity cannot sink or tip it and the
legs stay in the standing pose.  Its Bullet base velocity stays zero (a base
angular velocity would drive the legs' joints); the plant's velocity is in
``robot_state``.  Its links are out of contact solving (collision mask 0),
so contacts never push it: a collision is detected with ``getClosestPoints``
(which ignores masks), not resolved.  [x, y] is PyBullet's base frame (the
trunk's centre of mass); the rear knees reach 0.354 m behind it.  Fixed
links are merged on load (12 links, not 21), which halves the per-step and
closest-point cost.

A cylinder obstacle (``ObstacleSpec.radius``) is a PyBullet cylinder
(collision margin 0), so closest points measure the true cylinder, not the
polygon the filter is given.

Lidars (``sim_bridge.lidar``) cast their rays into ``ray_scene()``, a second
PyBullet client made on first use: every present obstacle copied at once with
Bullet's default collision margin (rays miss most margin-0 shapes, and a
lazily made body cannot be seen before it exists), each robot as the upright
cylinder of its footprint ``radius`` over its body's z range, moved to the
current time on each call.  The world's own bodies, physics, closest points
and collision checks never see it.

Crazyflie 2.1 (``assets/crazyflie21.urdf``) is a free rigid body with zero
linear and angular damping (PyBullet's default 0.04 is a hidden drag) and
collision margin.  Every physics step each rotor's thrust f_i is an
external force [0, 0, f_i] in the body frame at ``cf.ROTOR_POSITIONS[i]``, plus
the yaw reaction torque tau_z = sum(s_i c f_i) = ``cf.MIXER[3] @ f``; rotor
thrusts are clipped to [0, MAX_ROTOR_THRUST].  Until the first command it holds
hover thrust.  State: [p, v (world), roll, pitch, yaw, w = R^T w_world (body)].
"""
import contextlib
import dataclasses
import math
import os
import sys
from pathlib import Path

import numpy as np
import pybullet as pb
import pybullet_data

from polyc2bf_ros.core.geometry.polygons import decompose_convex, is_convex
from polyc2bf_ros.core.models import crazyflie as cf

GRAVITY = cf.GRAVITY
# Unicycle plant limits (at least the filter's unicycle bounds, so its inputs are realisable).
QUADRUPED_MAX_SPEED = 2.0             # m/s
QUADRUPED_MAX_TURN_RATE = 3.0         # rad/s
QUADRUPED_MAX_ACCEL = 2.0             # m/s^2
QUADRUPED_MAX_ANGULAR_ACCEL = 4.0     # rad/s^2
A1_URDF = 'a1/a1.urdf'
A1_STANDING_POSE = (0.0, 0.9, -1.8)   # hip, thigh, calf [rad], the same for all four legs
# Asleep and never woken: Bullet neither integrates the body nor applies gravity to it.
ASLEEP = pb.ACTIVATION_STATE_SLEEP | pb.ACTIVATION_STATE_DISABLE_WAKEUP
DIFF_DRIVE_HEIGHT = 0.25              # m, the disc's height (a Clearpath Jackal is 0.25 m)
DIFF_DRIVE_MASS = 15.0                # kg (never integrated: only "dynamic" for contacts)
CRAZYFLIE_URDF = Path(__file__).resolve().parent / 'assets' / 'crazyflie21.urdf'
CRAZYFLIE_HALF_HEIGHT = 0.015         # m, half the collision cylinder's length
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
FOOTPRINT_SEGMENTS = 16               # vertices of a robot's footprint circle


@dataclasses.dataclass(frozen=True, eq=False)
class Footprint:
    """An obstacle as published: CCW polygon (k, 2), z range, velocity [vx, vy, vz].

    ``index`` is its place in the scenario's obstacle list (``robot`` False) or
    robot list (``robot`` True): a stable identity while others come and go.
    """

    name: str
    polygon: np.ndarray
    z_min: float
    z_max: float
    velocity: np.ndarray
    index: int
    robot: bool = False


def _yaw_quaternion(yaw):
    """Return the quaternion [x, y, z, w] of a rotation by ``yaw`` about z."""
    return (0.0, 0.0, math.sin(0.5 * yaw), math.cos(0.5 * yaw))


def _finite(cmd, size, what):
    """Return ``cmd`` as a float array of ``size`` finite values or raise ValueError."""
    array = np.asarray(cmd, dtype=float).ravel()
    if array.size != size or not np.isfinite(array).all():
        raise ValueError(f'{what} must be {size} finite numbers, got {cmd!r}')
    return array


class _Obstacle:
    """Static, constant-velocity or trajectory prism: a mass-0 body per convex part, one anchor.

    It is present from ``appear()`` on (at construction when ``appear_at`` is 0); its
    bodies are made then, or with ``lazy`` on the first ``bodies_at``.  ``exact``: collision
    margin 0 (exact closest points; rays miss most such shapes), else Bullet's default.
    A moving one is translated by ``offset(t)`` (``ObstacleSpec.offset``): v (t - t_a), or
    p(t) - p(t_a) along its ``trajectory``, whose ``velocity(t)`` its footprint carries.
    """

    def __init__(self, spec, index, client, lazy, exact=True):
        """Describe the prism; part vertices are relative to the footprint's vertex mean."""
        self.spec = spec
        self.client = client
        self.exact = exact
        self.moving = spec.moving
        self.trajectory = spec.trajectory
        if self.trajectory is not None:  # where the trajectory is when ``polygon`` holds
            self.origin = np.asarray(self.trajectory.position(spec.appear_at), dtype=float)
        self.anchor = np.mean(spec.polygon, axis=0)
        velocity = np.append(spec.velocity, 0.0)
        self.footprint = Footprint(spec.name, spec.polygon, spec.z[0], spec.z[1], velocity,
                                   index)
        self.bodies, self.heights = [], []  # a body per part, and its frame's z
        self.lower = spec.polygon.min(axis=0)
        self.upper = spec.polygon.max(axis=0)
        self.lazy = lazy
        self.present = False
        if spec.appear_at <= 0.0:
            self.appear(0.0)

    def _shapes(self):
        """Return (collision shape, z of the body frame) per body: a cylinder, or mesh parts."""
        z_min, z_max = self.spec.z
        if self.spec.radius is not None:
            shape = pb.createCollisionShape(pb.GEOM_CYLINDER, radius=self.spec.radius,
                                            height=z_max - z_min, physicsClientId=self.client)
            return [(shape, 0.5 * (z_min + z_max))]
        polygon = self.spec.polygon
        shapes = []
        for part in [polygon] if is_convex(polygon) else decompose_convex(polygon):
            local = part - self.anchor
            vertices = [(x, y, z) for z in self.spec.z for x, y in local]
            shapes.append((pb.createCollisionShape(pb.GEOM_MESH, vertices=vertices,
                                                   physicsClientId=self.client), 0.0))
        return shapes

    def appear(self, time):
        """Make it present at ``time``, with its bodies unless they are made on first use."""
        self.present = True
        if not self.lazy:
            self.bodies_at(time)

    def bodies_at(self, time):
        """Return its bodies, made first (a cylinder, or a convex mesh per part) if need be."""
        if not self.bodies:
            for shape, z in self._shapes():
                body = pb.createMultiBody(0.0, shape, basePosition=(*self.anchor, z),
                                          physicsClientId=self.client)
                self.heights.append(z)
                if self.exact:
                    pb.changeDynamics(body, -1, collisionMargin=0.0, physicsClientId=self.client)
                self.bodies.append(body)
            if self.moving:
                self.place(time)
        return self.bodies

    def offset(self, time):
        """Return the translation since it appeared: v (t - t_a), or p(t) - p(t_a)."""
        if self.trajectory is None:
            return self.spec.velocity * (time - self.spec.appear_at)
        return np.asarray(self.trajectory.position(time), dtype=float) - self.origin

    def place(self, time):
        """Move every part to its position at ``time`` (nothing while it has no bodies)."""
        if not self.bodies:
            return
        x, y = self.anchor + self.offset(time)
        for body, z in zip(self.bodies, self.heights):
            pb.resetBasePositionAndOrientation(body, (x, y, z), (0.0, 0.0, 0.0, 1.0),
                                               physicsClientId=self.client)

    def footprint_at(self, time):
        """Return the published footprint at ``time``."""
        if not self.moving:
            return self.footprint
        spec = self.spec
        velocity = self.footprint.velocity
        if self.trajectory is not None:  # the instantaneous velocity
            velocity = np.append(self.trajectory.velocity(time), 0.0)
        return Footprint(spec.name, spec.polygon + self.offset(time), spec.z[0], spec.z[1],
                         velocity, self.footprint.index)


class _Robot:
    """Shared parts of the plants: the body, its footprint circle, reach and height.

    ``COMMAND_KINDS``: the kinds ``set_command`` takes, the default first;
    ``BULLET_STEPS``: Bullet integrates the body (else the plant places it).
    """

    COMMAND_KINDS = ()
    BULLET_STEPS = False

    def __init__(self, spec, body, client):
        """Measure the body: ``reach`` [m] bounds its horizontal extent from the base."""
        self.spec = spec
        self.body = body
        self.client = client
        self.index = 0  # place in the scenario's robot list, set by SimWorld
        angles = np.linspace(0.0, 2.0 * np.pi, FOOTPRINT_SEGMENTS, endpoint=False)
        self.circle = spec.radius * np.column_stack([np.cos(angles), np.sin(angles)])
        base = np.array(pb.getBasePositionAndOrientation(body, physicsClientId=client)[0])
        boxes = np.array([pb.getAABB(body, link, physicsClientId=client)
                          for link in range(-1, pb.getNumJoints(body, physicsClientId=client))])
        far = np.max(np.abs(boxes[:, :, :2] - base[:2]), axis=1)
        self.reach = float(np.max(np.hypot(far[:, 0], far[:, 1])))
        self.top = float(boxes[:, 1, 2].max() - base[2])
        self.links = len(boxes)

    def centre(self):
        """Return the base's [x, y] (2,)."""
        return self.extent()[0][:2]

    def before_physics(self):
        """Apply this step's forces (none by default)."""

    def after_physics(self, dt):
        """Update after the physics step (nothing by default)."""

    def sync(self):
        """Bring the Bullet body up to date with the plant (nothing by default)."""


@contextlib.contextmanager
def _quiet_stdout():
    """Silence file descriptor 1 for the block (Bullet prints every merged URDF link)."""
    sys.stdout.flush()
    saved = os.dup(1)
    try:
        with open(os.devnull, 'wb') as null:
            os.dup2(null.fileno(), 1)
        yield
    finally:
        os.dup2(saved, 1)
        os.close(saved)


class _Unicycle(_Robot):
    """The acceleration-limited unicycle plant of a kinematic body (the module docstring).

    The body is kept asleep and out of contact solving; its base sits at ``height``.
    """

    COMMAND_KINDS = ('velocity', 'acceleration')

    def __init__(self, spec, body, client, height):
        """Put ``body`` to sleep for good, drop it from contacts, start from the spec's pose."""
        for link in range(-1, pb.getNumJoints(body, physicsClientId=client)):
            pb.setCollisionFilterGroupMask(body, link, 0, 0, physicsClientId=client)
        pb.changeDynamics(body, -1, activationState=ASLEEP, physicsClientId=client)
        x, y, yaw = spec.start
        self.height = height
        pb.resetBasePositionAndOrientation(body, (x, y, height), _yaw_quaternion(yaw),
                                           physicsClientId=client)
        super().__init__(spec, body, client)
        self.state = np.array([x, y, yaw, 0.0, 0.0])
        self.command = (0.0, 0.0)
        self.velocity_mode = True
        self.actuator_tau = 0.0  # s: the velocity loop's first-order lag (0: at once)

    def set_command(self, cmd, kind):
        """Hold [v, omega] (kind 'velocity') or [a, alpha] (kind 'acceleration')."""
        self.command = tuple(_finite(cmd, 2, f'{self.spec.name} {kind} command').tolist())
        self.velocity_mode = kind == 'velocity'

    def after_physics(self, dt):
        """Integrate the unicycle over dt; the Bullet base follows on ``sync()``."""
        x, y, theta, v, omega = self.state.tolist()
        a, alpha = self.command
        if self.velocity_mode:
            lag = max(self.actuator_tau, dt)
            a, alpha = (a - v) / lag, (alpha - omega) / lag
        a = min(max(a, -QUADRUPED_MAX_ACCEL), QUADRUPED_MAX_ACCEL)
        alpha = min(max(alpha, -QUADRUPED_MAX_ANGULAR_ACCEL), QUADRUPED_MAX_ANGULAR_ACCEL)
        v_new = min(max(v + a * dt, -QUADRUPED_MAX_SPEED), QUADRUPED_MAX_SPEED)
        omega_new = min(max(omega + alpha * dt, -QUADRUPED_MAX_TURN_RATE),
                        QUADRUPED_MAX_TURN_RATE)
        speed, turn = 0.5 * (v + v_new), 0.5 * (omega + omega_new)
        heading = theta + 0.5 * turn * dt
        x += speed * math.cos(heading) * dt
        y += speed * math.sin(heading) * dt
        theta += turn * dt
        self.state[:] = x, y, theta, v_new, omega_new

    def sync(self):
        """Put the base at the plant's pose, upright at its height."""
        x, y, theta = self.state[:3].tolist()
        pb.resetBasePositionAndOrientation(self.body, (x, y, self.height),
                                           _yaw_quaternion(theta), physicsClientId=self.client)

    def robot_state(self):
        """Return the unicycle state [x, y, theta, v, omega]."""
        return self.state.copy()

    def body_twist(self):
        """Return the body-frame twist (vx, vy, vz, wx, wy, wz) = (v, 0, 0, 0, 0, omega)."""
        return (float(self.state[3]), 0.0, 0.0, 0.0, 0.0, float(self.state[4]))

    def centre(self):
        """Return the plant's [x, y] (2,)."""
        return self.state[:2].copy()

    def extent(self):
        """Return position (3,), world velocity (3,) and z range of the body."""
        x, y, theta, v, _ = self.state
        velocity = np.array([v * math.cos(theta), v * math.sin(theta), 0.0])
        return np.array([x, y, self.height]), velocity, 0.0, self.height + self.top


class _Quadruped(_Unicycle):
    """Unitree A1: the unicycle plant carrying the standing A1 (fixed links merged)."""

    def __init__(self, spec, client, ground):
        """Load the A1 standing at the start pose, joint motors off.

        The standing height is the distance from the legs to the ``ground`` body
        when the base is at z = 1: base z = 1 - that distance puts the feet on z = 0.
        """
        x, y, yaw = spec.start
        with _quiet_stdout():
            body = pb.loadURDF(A1_URDF, (x, y, 1.0), _yaw_quaternion(yaw),
                               flags=pb.URDF_MERGE_FIXED_LINKS, physicsClientId=client)
        joints = range(pb.getNumJoints(body, physicsClientId=client))
        for joint in joints:  # merged: hip, thigh, calf of each leg in turn
            pb.resetJointState(body, joint, A1_STANDING_POSE[joint % 3], physicsClientId=client)
        # No joint motors: Bullet would still solve their constraints for a sleeping body.
        pb.setJointMotorControlArray(body, list(joints), pb.VELOCITY_CONTROL,
                                     forces=[0.0] * len(joints), physicsClientId=client)
        gap = min(point[8] for point in pb.getClosestPoints(body, ground, 1.0,
                                                              physicsClientId=client))
        super().__init__(spec, body, client, 1.0 - gap)


class _DiffDrive(_Unicycle):
    """Diff-drive base: the unicycle plant carrying an upright cylinder of the spec's radius."""

    def __init__(self, spec, client, ground):
        """Create the disc (collision margin 0) standing on the ground at the start pose."""
        shape = pb.createCollisionShape(pb.GEOM_CYLINDER, radius=spec.radius,
                                        height=DIFF_DRIVE_HEIGHT, physicsClientId=client)
        body = pb.createMultiBody(DIFF_DRIVE_MASS, shape, physicsClientId=client)
        pb.changeDynamics(body, -1, collisionMargin=0.0, physicsClientId=client)
        super().__init__(spec, body, client, 0.5 * DIFF_DRIVE_HEIGHT)


class _Crazyflie(_Robot):
    """Crazyflie 2.1 rigid body driven by four rotor thrusts (see the module docstring)."""

    COMMAND_KINDS = ('thrusts', 'wrench')
    BULLET_STEPS = True

    def __init__(self, spec, client, ground):
        """Load the URDF at the start pose with its own inertia and zero damping."""
        x, y, z, yaw = spec.start
        body = pb.loadURDF(str(CRAZYFLIE_URDF), (x, y, z), _yaw_quaternion(yaw),
                           flags=pb.URDF_USE_INERTIA_FROM_FILE, physicsClientId=client)
        pb.changeDynamics(body, -1, linearDamping=0.0, angularDamping=0.0, collisionMargin=0.0,
                          physicsClientId=client)
        super().__init__(spec, body, client)
        self.rotors = [tuple(r) for r in cf.ROTOR_POSITIONS]
        self.thrusts = np.full(4, cf.HOVER_ROTOR_THRUST)
        self.target = self.thrusts.copy()
        self.yaw_torque = 0.0
        self.actuator_tau = 0.0  # s: the rotors' first-order lag (0: at once)

    def set_command(self, cmd, kind):
        """Hold rotor thrusts f (kind 'thrusts') or f = M^-1 [T, tau] (kind 'wrench'), clipped."""
        values = _finite(cmd, 4, f'{self.spec.name} {kind} command')
        if kind == 'wrench':
            values = cf.thrusts_from_wrench(values)
        self.target = np.clip(values, 0.0, cf.MAX_ROTOR_THRUST)
        if not self.actuator_tau:
            self.thrusts = self.target
            self.yaw_torque = float(cf.MIXER[3] @ self.thrusts)

    def before_physics(self):
        """Apply each rotor's thrust at its position and the yaw reaction torque, body frame.

        With ``actuator_tau`` the thrusts first move towards the commanded ones to first
        order over the step (``dt``, set with the lag).
        """
        if self.actuator_tau:
            self.thrusts = self.thrusts + (self.target - self.thrusts) * min(
                self.dt / self.actuator_tau, 1.0)
            self.yaw_torque = float(cf.MIXER[3] @ self.thrusts)
        for thrust, rotor in zip(self.thrusts, self.rotors):
            pb.applyExternalForce(self.body, -1, (0.0, 0.0, thrust), rotor, pb.LINK_FRAME,
                                  physicsClientId=self.client)
        pb.applyExternalTorque(self.body, -1, (0.0, 0.0, self.yaw_torque), pb.LINK_FRAME,
                               physicsClientId=self.client)

    def robot_state(self):
        """Return [p, v, roll, pitch, yaw, body rates] read from PyBullet."""
        position, quaternion = pb.getBasePositionAndOrientation(self.body,
                                                                physicsClientId=self.client)
        velocity, omega = pb.getBaseVelocity(self.body, physicsClientId=self.client)
        rotation = np.reshape(pb.getMatrixFromQuaternion(quaternion), (3, 3))
        euler = pb.getEulerFromQuaternion(quaternion)
        return np.concatenate([position, velocity, euler, rotation.T @ omega])

    def body_twist(self):
        """Return the body-frame twist (R^T v_world, R^T w_world) as a 6-tuple."""
        _, quaternion = pb.getBasePositionAndOrientation(self.body, physicsClientId=self.client)
        velocity, omega = pb.getBaseVelocity(self.body, physicsClientId=self.client)
        rotation = np.reshape(pb.getMatrixFromQuaternion(quaternion), (3, 3))
        return tuple((rotation.T @ np.array([velocity, omega]).T).T.ravel().tolist())

    def floor_gap(self):
        """Return the height [m] of the body's lowest point above the ground plane (z = 0).

        The collision cylinder (radius r, half-height h) tilted by phi from upright reaches
        down to z_c - h cos(phi) - r sin(phi); at or below 0 it touches the floor.
        """
        position, quaternion = pb.getBasePositionAndOrientation(self.body,
                                                                physicsClientId=self.client)
        up = abs(pb.getMatrixFromQuaternion(quaternion)[8])  # cos(phi): R[2, 2]
        return (position[2] - CRAZYFLIE_HALF_HEIGHT * up
                - cf.BODY_RADIUS * math.sqrt(max(0.0, 1.0 - up * up)))

    def extent(self):
        """Return position (3,), world velocity (3,) and z range of the body."""
        position = np.array(pb.getBasePositionAndOrientation(
            self.body, physicsClientId=self.client)[0])
        velocity = np.array(pb.getBaseVelocity(self.body, physicsClientId=self.client)[0])
        return (position, velocity, position[2] - CRAZYFLIE_HALF_HEIGHT,
                position[2] + CRAZYFLIE_HALF_HEIGHT)



class _RayScene:
    """What lidars see of a world: ray-only copies of its bodies in a PyBullet client of their own.

    Every obstacle is copied as soon as it is present (not on first use: a ray cannot ask
    for the bodies it would hit) with Bullet's default collision margin (rays miss most
    shapes of margin 0), and every robot is an upright cylinder of its footprint
    ``radius`` over its body's z range (a robot's CYLINDER marker, as the filter models
    it).  ``sync(time)`` moves them to the world's state.  Nothing here takes part in the
    world's physics, contacts or closest points: it is another client.
    """

    def __init__(self, obstacles, plants):
        """Connect a DIRECT client; copy the present obstacles, make a proxy per robot."""
        self.client = pb.connect(pb.DIRECT)
        self._sources = obstacles
        self._copies = [_Obstacle(o.spec, o.footprint.index, self.client, lazy=False,
                                  exact=False) for o in obstacles]
        self._plants = plants
        self.proxies = {}
        for plant in plants:
            _, _, z_min, z_max = plant.extent()
            shape = pb.createCollisionShape(pb.GEOM_CYLINDER, radius=plant.spec.radius,
                                            height=z_max - z_min, physicsClientId=self.client)
            self.proxies[plant.spec.name] = pb.createMultiBody(0.0, shape,
                                                               physicsClientId=self.client)
        self.sync(0.0)

    def sync(self, time):
        """Copy pop-ups that have appeared, move moving obstacles and robot proxies to ``time``."""
        for source, copy in zip(self._sources, self._copies):
            if source.present and not copy.present:
                copy.appear(time)
            elif copy.moving and copy.present:
                copy.place(time)
        for plant in self._plants:
            position, _, z_min, z_max = plant.extent()
            pb.resetBasePositionAndOrientation(
                self.proxies[plant.spec.name], (position[0], position[1], 0.5 * (z_min + z_max)),
                (0.0, 0.0, 0.0, 1.0), physicsClientId=self.client)

    def close(self):
        """Disconnect the client."""
        pb.disconnect(physicsClientId=self.client)


# Robot type (``sim_bridge.robots.ROBOT_TYPES``): its plant, built as ``plant(spec, client,
# ground)`` with the ground plane's body id.
PLANTS = {'quadruped': _Quadruped, 'diff_drive': _DiffDrive, 'crazyflie': _Crazyflie}


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
        self._rays = None  # the lidars' _RayScene, made by ray_scene()
        self._client = pb.connect(pb.GUI if gui else pb.DIRECT)
        client = self._client
        pb.setAdditionalSearchPath(pybullet_data.getDataPath(), physicsClientId=client)
        pb.setGravity(0.0, 0.0, -GRAVITY, physicsClientId=client)
        pb.setTimeStep(self.dt, physicsClientId=client)
        pb.setPhysicsEngineParameter(deterministicOverlappingPairs=1, physicsClientId=client)
        ground = pb.loadURDF('plane.urdf', physicsClientId=client)
        self._obstacles = [_Obstacle(spec, index, client, lazy=not gui)
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

        The scene (``_RayScene``) is made on the first call and moved to the current time
        on every call; the world's own client, bodies and metrics are untouched by it.
        """
        if self._rays is None:
            self._rays = _RayScene(self._obstacles, self._plants)
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
        if isinstance(plant, _Crazyflie):  # a flying body: the floor is an obstacle too
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
