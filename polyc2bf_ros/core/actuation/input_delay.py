"""Commands in flight and a lagging base: where the robot is when the next command acts.

A velocity-commanded base acts on a command ``command_latency`` L after it is published
(transport plus actuation delay), and its velocity loop follows the command to first
order with time constant ``actuator_tau`` tau, within its acceleration limits::

    v_dot = clip((v_cmd(t - L) - v) / tau)              (tau = 0: the command is met at once)

The filter's model takes the acceleration u as its input, acting at once.  Two changes
make the two agree (design.md 3.13):

1. **Predictor for input delay.**  What the filter decides at t acts from t + L; until
   then the commands already published act.  So the filter decides at the predicted
   state x(t + L): the measured x(t) carried over [t, t + L] by the base model above with
   the commands in flight (the standard predictor feedback for input delay: Smith, 1957;
   Krstic, *Delay Compensation for Nonlinear, Adaptive, and PDE Systems*, 2009), midpoint
   steps of at most one control period, and obstacles extrapolated as far.  Before any
   command was published the base is taken to hold its measured velocity.
2. **The command that realises u.**  Over a period T the base gains
   ``(v_cmd - v)(1 - exp(-T / tau))`` of velocity, so the filter's u (held for T, ``v + u
   T``) is published as::

       v_cmd = v + u T / (1 - exp(-T / tau))             (tau = 0: v + u T)

   and the braking check's stop follows the base's own (``brake_time_constant`` at least
   tau: a base told to stop decelerates as ``-v / tau``).

3. **A base that lags more, or acts later, than told** (``braking_plan``).  With the true
   time constant up to tau + dtau, a command scaled for tau realises only
   ``(1 - exp(-T / (tau + dtau))) / (1 - exp(-T / tau))`` of the velocity change asked;
   with the true latency up to L + dL the base is, when a command acts, slower than
   predicted by what it braked over dL, and each braking command asks less than meant.
   The braking check plans its stops at the deceleration such a base realises, after a
   coast for the predicted state's error (``RobotModel.plan_braking``).

Velocity models only (the quadrotor's rotors lag in ``rotor_lag``).  The predicted heading of a
point mass is the measured one (its yaw is not in the state; over a few tens of
milliseconds of latency the difference is the yaw rate times L).
"""
import collections
import math

import numpy as np

from polyc2bf_ros.core.actuation.command_interface import VelocityCommandInterface


def braking_plan(period, actuator_tau, tau_error, latency_error):
    """Return (share, coast) of ``RobotModel.plan_braking`` under bounded mismatch.

    The base's time constant may be up to ``tau_error`` dtau [s] above ``actuator_tau`` tau
    and its latency up to ``latency_error`` dL [s] above the one told.  Braking, the filter
    asks each period for a change c = a T g of the velocity it predicts for when the
    command acts (``InputDelay.gain`` g = 1 / rho^, rho(tau) = 1 - e^{-T / tau}, 1 for
    tau = 0).  A base with rho = rho(tau + dtau) realises rho of what it is sent, and acting
    dL later it is a_eff dL slower than predicted by then, so per period
    a_eff T = (a T g - a_eff dL) rho:

        share = a_eff / a = (rho / rho^) T / (T + rho dL)

    And the stop starts from a state off by v (dL + dtau) in position and a (dL + dtau) in
    speed, which lengthens it by about v (dL + dtau) more: coast = 2 (dL + dtau), design.md
    3.13's eps less the odometry's s (module docstring, item 3).
    """
    def realised(tau):
        """Return rho: the share of a velocity step a base of time constant tau makes in T."""
        return -math.expm1(-period / tau) if tau > 0.0 else 1.0

    for name, value in (('actuator_tau_error', tau_error),
                        ('command_latency_error', latency_error)):
        if not (math.isfinite(value) and value >= 0.0):
            raise ValueError(f'{name} must be a finite number >= 0, got {value!r}')
    rho = realised(actuator_tau + tau_error)
    share = rho / realised(actuator_tau) * period / (period + rho * latency_error)
    return share, 2.0 * (latency_error + tau_error)


class InputDelay:
    """The commands in flight to one base, and its first-order response (module docstring)."""

    def __init__(self, model, latency, actuator_tau, period):
        """For ``model`` (a velocity model), L = ``latency`` [s], tau = ``actuator_tau`` [s]."""
        if not (math.isfinite(latency) and latency >= 0.0):
            raise ValueError(f'command_latency must be a finite number >= 0, got {latency!r}')
        if not (math.isfinite(actuator_tau) and actuator_tau >= 0.0):
            raise ValueError(f'actuator_tau must be a finite number >= 0, got {actuator_tau!r}')
        self.model = model
        self.latency, self.tau, self.period = float(latency), float(actuator_tau), float(period)
        steps = max(1, math.ceil(self.latency / self.period - 1e-9))
        self._step = self.latency / steps if self.latency else self.period
        self._steps = steps if self.latency else 0
        # The base's response as the filter's own velocity interface: u = (v_cmd - v) / tau.
        self._base = VelocityCommandInterface(model.name, max(self.tau, self._step), self._step)
        self._sent = collections.deque()  # (publish time, command)
        # v_cmd = v + u T gain: 1 / (1 - exp(-T / tau)), about tau / T for a slow base.
        self.gain = 1.0 / -math.expm1(-self.period / self.tau) if self.tau else 1.0

    @property
    def active(self):
        """Return True when there is a latency to predict over."""
        return self._steps > 0

    def published(self, now, command):
        """Note ``command`` (command coordinates) as published at ``now`` [s]."""
        if not self._steps:
            return  # nothing is in flight without a latency
        self._sent.append((float(now), np.array(command, dtype=float)))
        # Keep the newest command that acts by now - L: it acts from the prediction's start.
        while len(self._sent) > 1 and self._sent[1][0] <= now - self.latency:
            self._sent.popleft()

    def predict(self, state, yaw, now):
        """Return the state at ``now`` + L from the measured ``state`` at ``now`` (a copy).

        The command acting at t is the newest published at or before t - L.
        """
        x = np.array(state, dtype=float)
        if not self._steps:
            return x
        sent = [item for item in self._sent if item[0] <= now]
        held = self._base.safe_command(x, np.zeros(self._base.velocity_dim), yaw)
        model, h = self.model, self._step
        for k in range(self._steps):
            t = now + k * h - self.latency
            command = held
            for stamp, value in sent:
                if stamp <= t + 1e-9:
                    command = value
            u = model.clip_input(self._base.nominal_input(x, command, yaw))
            middle = x + 0.5 * h * model.state_derivative(x, u)
            x = x + h * model.state_derivative(middle, u)
        return x

    def reset(self):
        """Forget the commands in flight (a new session, a jump back in time)."""
        self._sent.clear()
