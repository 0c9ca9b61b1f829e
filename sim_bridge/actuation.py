"""How the arena's plants take commands and report odometry: exact, or as a real base does.

By default the lockstep arena is exact: a command acts from the next physics step, a
velocity command is met within the plant's acceleration limits at once, and odometry is
the plant's true state.  ``Actuation`` makes it realistic (``evaluate --latency S
--actuator-tau S --odom-noise M``):

- ``latency`` [s]: a command reaches the plant this long after the filter published it
  (transport plus actuation delay), rounded to physics steps; until the first one arrives
  the plant holds its initial command (rest);
- ``actuator_tau`` [s]: the plant's velocity loop follows a velocity command to first
  order, ``a = (v_cmd - v) / tau`` (within its acceleration limits), and a Crazyflie's
  rotors their thrusts, ``f_dot = (f_cmd - f) / tau``; 0: at once;
- ``odom_noise`` [m]: the position the filter and its nominal controller get is the
  plant's plus independent Gaussian noise of this standard deviation per axis and period
  (the heading's noise is ``odom_noise`` / 1 m rad), seeded per robot; the referee and
  the records keep the true state.

Each run's records state the settings (``record``), and the tables' header line
(``describe``).
"""
import collections
import dataclasses
import math

import numpy as np

FIELDS = ('latency', 'actuator_tau', 'odom_noise')
HEADING_NOISE_PER_METRE = 1.0  # rad of heading noise per metre of position noise


@dataclasses.dataclass(frozen=True)
class Actuation:
    """Command latency [s], actuator time constant [s] and odometry noise [m] (module doc)."""

    latency: float = 0.0
    actuator_tau: float = 0.0
    odom_noise: float = 0.0
    seed: int = 0

    def validate(self):
        """Return self; raise ValueError naming the first field that is not finite >= 0."""
        for name in FIELDS:
            value = getattr(self, name)
            if isinstance(value, bool) or not isinstance(value, (int, float)) \
                    or not math.isfinite(value) or value < 0.0:
                raise ValueError(f'{name} must be a finite number >= 0, got {value!r}')
        return self

    @property
    def exact(self):
        """Return True when nothing is added (the arena's lockstep default)."""
        return not any(getattr(self, name) for name in FIELDS)

    def record(self):
        """Return the record's ``latency_s``, ``actuator_tau_s`` and ``odom_noise_m``."""
        return {'latency_s': self.latency, 'actuator_tau_s': self.actuator_tau,
                'odom_noise_m': self.odom_noise}


def describe(record):
    """Return a table header's words for a record's actuation dict (None: exact)."""
    if not record or not any(record.values()):
        return 'exact (commands act at once, odometry is the true state)'
    return (f"command latency {record['latency_s']:g} s, actuator time constant "
            f"{record['actuator_tau_s']:g} s, odometry noise {record['odom_noise_m']:g} m")


class CommandPipe:
    """The commands on their way to one plant: what acts at a time, ``latency`` after sending."""

    def __init__(self, latency, initial):
        """Start with ``initial`` in effect (the plant's command before any arrives)."""
        self.latency = float(latency)
        self._queue = collections.deque()
        self._current = initial

    def send(self, time, command):
        """Queue ``command``, published at ``time`` [s]."""
        self._queue.append((time + self.latency, command))

    def at(self, time):
        """Return the command in effect at ``time``: the newest that has arrived by then."""
        # Half a nanosecond of slack: arrival times are sums of float periods.
        while self._queue and self._queue[0][0] <= time + 5e-10:
            self._current = self._queue.popleft()[1]
        return self._current


class Odometry:
    """Odometry as the robot's filter gets it: the true state, or with noise (module doc)."""

    def __init__(self, noise, seed, position_index=(0, 1), yaw_index=None):
        """Noise [m] on the ``position_index`` entries, noise / 1 m rad on ``yaw_index``."""
        self.noise = float(noise)
        self._rng = np.random.default_rng(seed)
        self._position, self._yaw = list(position_index), yaw_index

    def read(self, state):
        """Return the state the filter gets (a copy when noisy)."""
        if not self.noise:
            return state
        noisy = np.array(state, dtype=float)
        noisy[self._position] += self._rng.normal(0.0, self.noise, len(self._position))
        if self._yaw is not None:
            noisy[self._yaw] += self._rng.normal(0.0, self.noise * HEADING_NOISE_PER_METRE)
        return noisy
