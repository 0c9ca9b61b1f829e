"""One filtered command, in the robot's own command units: what the node decides per step.

The barrier functions act on each model's input ``u`` (accelerations, or rotor
thrusts for the quadrotor).  Robots take commands in other units; this module
is the single place that converts, so the ``safety_filter`` node, offline bag
replay and the in-process evaluation make the same decision for the same
inputs.

Command vectors per model:

- velocity models (``core.actuation.command_interface``): ``unicycle`` ``[v, omega]``,
  ``point_mass_2d`` ``[vx, vy]``, ``point_mass_3d`` ``[vx, vy, vz]`` (heading
  frame)::

      u_nom  = (Rz(yaw) v_cmd - v) / tau,     v_safe = Rz(yaw)^T (v + u_safe T)

- ``quadrotor``: the wrench ``[T, tau_x, tau_y, tau_z]`` (collective thrust and
  body torques), mixed into rotor thrusts and back (``core.models.crazyflie``)::

      f_nom = M^-1 w_nom,                    w_safe = M f_safe

A stop is the zero velocity command, or the wrench of the quadrotor's braking
(hover) input.  Non-finite input of any kind yields the stop and the
``invalid_input`` status, never NaN.
"""
import math

import numpy as np

from polyc2bf_ros.core.actuation.command_interface import VELOCITY_MODELS, VelocityCommandInterface
from polyc2bf_ros.core.actuation.input_delay import InputDelay
from polyc2bf_ros.core.actuation.rotor_lag import RotorLag
from polyc2bf_ros.core.models import crazyflie
from polyc2bf_ros.core.safety_filter import FilterInfo, FilterStatus, SafetyFilter


class CommandFilter:
    """``SafetyFilter`` behind the robot's command interface (see the module docstring)."""

    def __init__(self, model, config, velocity_tau=0.0, command_latency=0.0, actuator_tau=0.0):
        """Filter ``model``'s commands with ``config``; ``velocity_tau`` 0 means one period.

        ``command_latency`` L, ``actuator_tau`` tau [s]: the base's
        (``core.actuation.input_delay``): the filter decides at the state predicted L ahead
        with the commands published since (``published``), and publishes the command a base
        lagging by tau turns into the filter's acceleration.  The quadrotor takes tau only,
        as its rotors' time constant (``core.actuation.rotor_lag``).
        """
        self.model = model
        self.safety_filter = SafetyFilter(model, config)
        self.velocity = model.name in VELOCITY_MODELS
        self.interface = self.delay = self.rotors = None
        if self.velocity:
            period = config.control_period
            self.interface = VelocityCommandInterface(model.name, velocity_tau or period, period)
            self.command_dim = self.interface.velocity_dim
            self.delay = InputDelay(model, command_latency, actuator_tau, period)
        else:
            if command_latency:
                raise ValueError(f'command_latency applies to velocity models '
                                 f'({", ".join(VELOCITY_MODELS)}), not {model.name}')
            if actuator_tau:
                self.rotors = RotorLag(actuator_tau, config.control_period, model.input_lower,
                                       model.input_upper)
            self.command_dim = 4

    def filter(self, state, yaw, command, obstacles, obstacle_age=0.0, now=None):
        """Return ``(safe command, FilterInfo)`` for a nominal ``command`` at ``state``.

        With a ``command_latency`` and the step's time ``now`` [s], at the state predicted
        for when the command acts, and the obstacles extrapolated as far.
        """
        if not (all(map(math.isfinite, command)) and math.isfinite(yaw)):
            info = FilterInfo(status=FilterStatus.INVALID_INPUT,
                              message='non-finite nominal command or yaw')
            return self.stop(state), info
        if self.delay is not None and self.delay.active and now is not None:
            state = self.delay.predict(state, yaw, now)
            obstacle_age += self.delay.latency
        if self.velocity:
            u_nom = self.interface.nominal_input(state, command, yaw)
        else:
            u_nom = crazyflie.thrusts_from_wrench(command)
        u_safe, info = self.safety_filter.step(state, obstacles, u_nom, obstacle_age)
        if info.status == FilterStatus.INVALID_INPUT:
            return self.stop(state), info
        if self.velocity:
            if self.delay.gain != 1.0:  # a lagging base (core.actuation.input_delay)
                u_safe = u_safe * self.delay.gain
            return self.interface.safe_command(state, u_safe, yaw), info
        if self.rotors is not None:  # rotors lagging by tau (core.actuation.rotor_lag)
            u_safe = self.rotors.command(u_safe)
        return crazyflie.wrench_from_thrusts(u_safe), info

    def published(self, now, command):
        """Note the command the node published at ``now`` (for the latency's predictor)."""
        if self.delay is not None:
            self.delay.published(now, command)
        elif self.rotors is not None:
            self.rotors.published(now, crazyflie.thrusts_from_wrench(command))

    def stop(self, state):
        """Return the stop command: zero velocity, or the quadrotor's braking wrench."""
        if self.velocity:
            return np.zeros(self.command_dim)
        return crazyflie.wrench_from_thrusts(self.model.braking_input(state))
