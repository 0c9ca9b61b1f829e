"""Rotors that follow their thrust commands late: the command that reaches the filter's thrusts.

A rotor's thrust f follows its command to first order with the time constant
``actuator_tau`` tau, ``f_dot = (f_cmd - f) / tau``, while the quadrotor model takes the
thrusts u as acting at once (paper, eq. 18).  Held over one period T from f, a command
gives ``f(T) = f_cmd + (f - f_cmd) e^{-T/tau}``, so::

    f_cmd = f + (u - f) / (1 - e^{-T/tau})          (within [0, max_rotor_thrust])

brings the rotors to u by the end of the period (the velocity models' version is in
``input_delay``).  The thrusts are not measured: they are estimated from the commands
published, through the same response (open loop), from the first command on, which the
rotors are taken to hold.  A clipped command reaches u later; the filter's margin
(``margin_gain``) covers the rest.
"""
import math

import numpy as np


class RotorLag:
    """The published thrust commands' first-order response, and the command that realises u."""

    def __init__(self, tau, period, lower, upper):
        """Rotors with time constant ``tau`` [s], stepped every ``period``, thrusts in bounds."""
        if not (math.isfinite(tau) and tau > 0.0):
            raise ValueError(f'actuator_tau must be a finite number > 0, got {tau!r}')
        self.tau, self.period = float(tau), float(period)
        self.decay = math.exp(-self.period / self.tau)
        self.gain = 1.0 / -math.expm1(-self.period / self.tau)
        self.lower, self.upper = np.asarray(lower, float), np.asarray(upper, float)
        self._thrusts = self._command = None  # no command published yet
        self._stamp = 0.0

    def command(self, u):
        """Return the thrust command that brings the rotors to ``u`` one period from now."""
        if self._command is None:
            return np.asarray(u, dtype=float)
        now = self._command + (self._thrusts - self._command) * self.decay
        return np.clip(now + (u - now) * self.gain, self.lower, self.upper)

    def published(self, now, thrusts):
        """Note the thrust command published at ``now`` [s]."""
        thrusts = np.asarray(thrusts, dtype=float)
        if self._command is None:
            self._thrusts = thrusts.copy()
        else:
            elapsed = max(float(now) - self._stamp, 0.0)
            self._thrusts = self._command + (self._thrusts - self._command) * math.exp(
                -elapsed / self.tau)
        self._command, self._stamp = thrusts.copy(), float(now)
