"""The simulated robots of a ``SimWorld``: one plant class per robot type (``PLANTS``).

Quadruped (Unitree A1, ``pybullet_data/a1/a1.urdf``, a dynamic body), diff-drive
base (an upright PyBullet cylinder of the scenario's ``radius`` and
``DIFF_DRIVE_HEIGHT``, a dynamic body) and Clearpath Jackal (a box of
``JACKAL_SIZE``) are the paper's acceleration-controlled unicycle: all are the one
plant below, driven by ``cmd_vel`` [v, omega], each with its own limits.  Its
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

Crazyflie 2.1 (``assets/crazyflie21.urdf``) is a free rigid body with zero
linear and angular damping (PyBullet's default 0.04 is a hidden drag) and
collision margin.  Every physics step each rotor's thrust f_i is an
external force [0, 0, f_i] in the body frame at ``cf.ROTOR_POSITIONS[i]``, plus
the yaw reaction torque tau_z = sum(s_i c f_i) = ``cf.MIXER[3] @ f``; rotor
thrusts are clipped to [0, MAX_ROTOR_THRUST].  Until the first command it holds
hover thrust.  State: [p, v (world), roll, pitch, yaw, w = R^T w_world (body)].
"""
import contextlib
import math
import os
import sys
from pathlib import Path

import numpy as np
import pybullet as pb

from polyc2bf_ros.core.models import crazyflie as cf
from sim_bridge.robots import JACKAL_SIZE

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
# Clearpath Jackal (its box: robots.JACKAL_SIZE): the limits of its diff_drive_controller
# (jackal/jackal, jackal_control/config/control.yaml): 2.0 m/s, 4.0 rad/s, 20.0 m/s^2,
# 25.0 rad/s^2.
JACKAL_MAX_SPEED = 2.0                # m/s
JACKAL_MAX_TURN_RATE = 4.0            # rad/s
JACKAL_MAX_ACCEL = 20.0               # m/s^2
JACKAL_MAX_ANGULAR_ACCEL = 25.0       # rad/s^2
CRAZYFLIE_URDF = Path(__file__).resolve().parent / 'assets' / 'crazyflie21.urdf'
CRAZYFLIE_HALF_HEIGHT = 0.015         # m, half the collision cylinder's length
FOOTPRINT_SEGMENTS = 16               # vertices of a robot's footprint circle


def _yaw_quaternion(yaw):
    """Return the quaternion [x, y, z, w] of a rotation by ``yaw`` about z."""
    return (0.0, 0.0, math.sin(0.5 * yaw), math.cos(0.5 * yaw))


def _finite(cmd, size, what):
    """Return ``cmd`` as a float array of ``size`` finite values or raise ValueError."""
    array = np.asarray(cmd, dtype=float).ravel()
    if array.size != size or not np.isfinite(array).all():
        raise ValueError(f'{what} must be {size} finite numbers, got {cmd!r}')
    return array


class Plant:
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


class UnicyclePlant(Plant):
    """The acceleration-limited unicycle plant of a kinematic body (the module docstring).

    The body is kept asleep and out of contact solving; its base sits at ``height``.
    ``LIMITS``: (v_max, omega_max, a_max, alpha_max).
    """

    COMMAND_KINDS = ('velocity', 'acceleration')
    LIMITS = (QUADRUPED_MAX_SPEED, QUADRUPED_MAX_TURN_RATE, QUADRUPED_MAX_ACCEL,
              QUADRUPED_MAX_ANGULAR_ACCEL)

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
        max_speed, max_turn_rate, max_accel, max_angular_accel = self.LIMITS
        if self.velocity_mode:
            lag = max(self.actuator_tau, dt)
            a, alpha = (a - v) / lag, (alpha - omega) / lag
        a = min(max(a, -max_accel), max_accel)
        alpha = min(max(alpha, -max_angular_accel), max_angular_accel)
        v_new = min(max(v + a * dt, -max_speed), max_speed)
        omega_new = min(max(omega + alpha * dt, -max_turn_rate), max_turn_rate)
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


class QuadrupedPlant(UnicyclePlant):
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


class DiffDrivePlant(UnicyclePlant):
    """Diff-drive base: the unicycle plant carrying an upright cylinder of the spec's radius."""

    def __init__(self, spec, client, ground):
        """Create the disc (collision margin 0) standing on the ground at the start pose."""
        shape = pb.createCollisionShape(pb.GEOM_CYLINDER, radius=spec.radius,
                                        height=DIFF_DRIVE_HEIGHT, physicsClientId=client)
        body = pb.createMultiBody(DIFF_DRIVE_MASS, shape, physicsClientId=client)
        pb.changeDynamics(body, -1, collisionMargin=0.0, physicsClientId=client)
        super().__init__(spec, body, client, 0.5 * DIFF_DRIVE_HEIGHT)


class JackalPlant(UnicyclePlant):
    """Clearpath Jackal: the unicycle plant carrying a box of ``JACKAL_SIZE``, its limits.

    The box is the body every contact and clearance is measured against (closest points),
    centred on the base; other robots' lidars see it as the cylinder of the scenario's
    ``radius`` (``ray_scene``).
    """

    LIMITS = (JACKAL_MAX_SPEED, JACKAL_MAX_TURN_RATE, JACKAL_MAX_ACCEL,
              JACKAL_MAX_ANGULAR_ACCEL)

    def __init__(self, spec, client, ground):
        """Create the box (collision margin 0) standing on the ground at the start pose."""
        length, width, height = JACKAL_SIZE
        shape = pb.createCollisionShape(pb.GEOM_BOX,
                                        halfExtents=(0.5 * length, 0.5 * width, 0.5 * height),
                                        physicsClientId=client)
        body = pb.createMultiBody(DIFF_DRIVE_MASS, shape, physicsClientId=client)
        pb.changeDynamics(body, -1, collisionMargin=0.0, physicsClientId=client)
        super().__init__(spec, body, client, 0.5 * height)


class CrazyfliePlant(Plant):
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


# Robot type (``sim_bridge.robots.ROBOT_TYPES``): its plant, built as ``plant(spec, client,
# ground)`` with the ground plane's body id.
PLANTS = {'quadruped': QuadrupedPlant, 'diff_drive': DiffDrivePlant, 'jackal': JackalPlant,
          'crazyflie': CrazyfliePlant}
