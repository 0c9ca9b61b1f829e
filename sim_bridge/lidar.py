"""A simulated planar 2-D lidar: one ``rayTestBatch`` per scan against a PyBullet world.

``Lidar(client, ignore, settings).scan((x, y, z, yaw))`` casts ``settings.beams``
rays in a level plane ``height`` above the robot's base, from the sensor origin
at ``mount`` = (x, y, yaw) in the base frame out to ``range_max``, and returns a
``Scan``: ranges [m] as float32, +inf where a beam has no return within
``range_max`` (REP 117).  A return is the distance to the first surface hit plus
Gaussian noise of ``noise_std`` (seeded; drawn for every beam each scan, so the
stream does not depend on the scene), clipped at 0.  Returns closer than
``range_min`` are reported as measured: consumers drop them, as LaserScan says.
Beam angles follow sensor_msgs/LaserScan (``LidarSettings``).  ``laser_scan``
builds the LaserScan (importing sensor_msgs when called, so ray casting needs
neither rclpy nor sensor_msgs) and ``mount_transform`` the static base -> laser
transform for ``sim_bridge.cdr.tf_message_cdr``.

The robot's own body: rays start at the sensor origin and a hit on an
``ignore``-d body (any of its links) is discarded: those beams are re-cast from
``RECAST_STEP`` beyond the hit point, in one further ``rayTestBatch`` of only
those beams per round, up to ``MAX_RECASTS`` rounds (enough for a quadruped's
legs; a beam still on the robot after that reads +inf).  Bullet reports no hit
for a ray that starts inside a convex shape, so a sensor inside its robot's
body sees straight through it, and the re-cast from just past an entry point
passes through that link.  Unlike starting rays outside the robot's reach,
this misses nothing between the robot's parts (between a quadruped's legs, or
an obstacle close to the body); it misses only surfaces within RECAST_STEP
behind an entry point, and an obstacle that penetrates the robot where a
re-cast starts (as it misses one the sensor itself is inside).

Modelled: an ideal time-of-flight sensor with one level scan plane (a tilted
base, e.g. a banking Crazyflie, still scans level; only the yaw is used),
every beam measured at the same instant (``time_increment`` 0), perfect
reflectivity (every surface returns, at any incidence), first-surface
distances as Bullet's ray test gives them (measured against exact geometry:
boxes within 1 mm, median 4e-8 m; cylinders median 0.1 mm, up to 2 cm; convex
meshes about their collision margin, 1 mm by default, short).  Not modelled:
beam divergence (a beam is an infinitely thin ray), multipath and mixed
pixels, intensities, motion distortion during a sweep, dropouts, range
quantisation.

Rays see only the bodies that exist, take part in collisions and have a
collision margin: Bullet's ray test misses most shapes of margin 0 (random
boxes and convex meshes: ~60 % of the beams that should hit them; cylinders
now and then).  A ``sim_bridge.world.SimWorld`` keeps its own bodies at margin
0 (for exact closest points) and makes them on first use, so ``RobotLidars``
scans the world's ray scene instead (``SimWorld.ray_scene``): a PyBullet
client of its own holding every present obstacle at Bullet's default margin
and each robot as the cylinder of its footprint radius, which the world's
contacts and clearances never see.

``RobotLidars(world, settings)`` puts a Lidar on robots of a SimWorld (frame
``<robot>/laser``) and scans every ``physics_rate / rate`` physics steps, a
whole number or refused (``scenario_specs.rate_steps``, as for the control rate);
the bridge publishes the scans, the in-process loop converts them as the node
does.

Cost per scan, 360 / 1081 beams, range_max 10 m (median of repeats, both cores
busy): no obstacles 0.55 / 1.8 ms (over half of it Python); a 10 m box room
0.9-1.5 / 2.8-4.7 ms; 100 cylinders in 10 x 10 m 13 / 37 ms; with every body
of a SimWorld made, ``cluttered`` (30 prisms) 3.5 / 11 ms and a BARN world
(211-237 cylinders) 14-17 / 44-51 ms.  It grows
with the shapes along each ray's whole length (casting in stages of growing
length saved a third in a BARN world), and a ray against a cylinder or convex
mesh costs several times one against a box.  ``threads`` = 2 nearly halved the
cylinder worlds' cost while a second core was idle, and gained nothing while
both were busy.
"""
import array
import dataclasses
import math
import numbers

import numpy as np
import pybullet as pb
import yaml

from sim_bridge.scenario_specs import rate_steps

MAX_BEAMS = 4096
# Re-casting a beam past a hit on the robot's own body starts this far beyond the hit [m].
RECAST_STEP = 1e-3
MAX_RECASTS = 16
# A field of view within this of 2 pi is a full circle [rad].
FULL_CIRCLE_TOLERANCE = 1e-9
# The fields a lidar's parameters set (the bridge's ``lidar.<field>``, ``--lidar FIELD=VALUE``).
PARAMETER_FIELDS = ('beams', 'field_of_view', 'range_min', 'range_max', 'rate', 'noise_std',
                    'height', 'mount')
SCAN_TOPIC = 'scan'  # relative to the robot's namespace


def _finite(value):
    """Return True for a finite real number (not a bool)."""
    return isinstance(value, numbers.Real) and not isinstance(value, bool) and math.isfinite(value)


def _number(settings, name, low=-math.inf, high=math.inf, low_open=False):
    """Return field ``name`` of ``settings`` as a float; ValueError naming it if out of range."""
    value = getattr(settings, name)
    ok = _finite(value)
    if ok:
        value = float(value)
        ok = (value > low if low_open else value >= low) and value <= high
    if not ok:
        bounds = ''
        if high < math.inf:
            bounds = f' in {"(" if low_open else "["}{low:g}, {high:g}]'
        elif low > -math.inf:
            bounds = f' {">" if low_open else ">="} {low:g}'
        raise ValueError(f'LidarSettings.{name} must be a finite number{bounds}, '
                         f'got {value!r}')
    return value


@dataclasses.dataclass(frozen=True)
class LidarSettings:
    """A lidar's parameters; ``validate()`` checks them.

    ``beams`` (1..MAX_BEAMS) over ``field_of_view`` [rad] in (0, 2 pi], centred on
    the sensor's x axis; ``range_min``, ``range_max`` [m]; ``rate`` [Hz] (the
    LaserScan's ``scan_time`` = 1 / rate; ``RobotLidars`` scans at it);
    ``noise_std`` [m]: Gaussian range noise; ``height`` [m]: the scan plane above
    the base; ``mount``: (x [m], y [m], yaw [rad]) of the sensor in the base frame;
    ``frame_id``: the sensor's frame.  Angles as in sensor_msgs/LaserScan:
    ``angle_min`` = -fov / 2, ``angle_increment`` = fov / beams for a full circle
    (the first and last beams do not coincide), else fov / (beams - 1) (fov for a
    single beam), ``angle_max`` = angle_min + (beams - 1) * increment.
    """

    beams: int = 360
    field_of_view: float = 2.0 * math.pi
    range_min: float = 0.05
    range_max: float = 10.0
    rate: float = 10.0
    noise_std: float = 0.0
    height: float = 0.0
    mount: tuple = (0.0, 0.0, 0.0)
    frame_id: str = 'laser'

    def validate(self):
        """Return self when every field is valid, else raise ValueError naming the field."""
        beams = self.beams
        if (not isinstance(beams, numbers.Integral) or isinstance(beams, bool)
                or not 1 <= beams <= MAX_BEAMS):
            raise ValueError(f'LidarSettings.beams must be an integer in 1..{MAX_BEAMS}, '
                             f'got {beams!r}')
        _number(self, 'field_of_view', 0.0, 2.0 * math.pi, low_open=True)
        range_min = _number(self, 'range_min', 0.0)
        _number(self, 'range_max', range_min, low_open=True)
        _number(self, 'rate', 0.0, low_open=True)
        _number(self, 'noise_std', 0.0)
        _number(self, 'height')
        try:
            mount = list(self.mount)
        except TypeError:
            mount = []
        if len(mount) != 3 or not all(map(_finite, mount)):
            raise ValueError(f'LidarSettings.mount must be 3 finite numbers (x, y, yaw), '
                             f'got {self.mount!r}')
        if not isinstance(self.frame_id, str) or not self.frame_id:
            raise ValueError(f'LidarSettings.frame_id must be a non-empty string, '
                             f'got {self.frame_id!r}')
        return self

    @property
    def full_circle(self):
        """Return True when the field of view is 2 pi (beams spaced fov / beams)."""
        return self.field_of_view > 2.0 * math.pi - FULL_CIRCLE_TOLERANCE

    @property
    def angle_min(self):
        """Return the first beam's angle [rad] in the sensor frame: -fov / 2."""
        return -0.5 * self.field_of_view

    @property
    def angle_increment(self):
        """Return the angle [rad] between beams (see the class docstring)."""
        if self.full_circle or self.beams == 1:
            return self.field_of_view / self.beams
        return self.field_of_view / (self.beams - 1)

    @property
    def angle_max(self):
        """Return the last beam's angle [rad]: angle_min + (beams - 1) * angle_increment."""
        return self.angle_min + (self.beams - 1) * self.angle_increment

    def angles(self):
        """Return every beam's angle [rad] in the sensor frame, (beams,)."""
        return self.angle_min + self.angle_increment * np.arange(self.beams)


@dataclasses.dataclass(frozen=True, eq=False)
class Scan:
    """One scan: ranges [m] (float32, +inf: no return) and where it was taken.

    ``bodies``: the PyBullet body each beam hit (-1: none), ground truth for
    tests and labels; ``origin``: the sensor's world position (3,); ``heading``:
    the world yaw [rad] of the sensor's x axis.
    """

    settings: LidarSettings
    ranges: np.ndarray
    bodies: np.ndarray
    origin: np.ndarray
    heading: float


class Lidar:
    """A lidar on a robot in PyBullet client ``client``, blind to the ``ignore`` bodies.

    ``ignore``: the robot's own body id or ids; ``seed``: the noise generator's
    seed; ``threads``: ``rayTestBatch``'s ``numThreads`` (1: the calling thread;
    0: Bullet decides).
    """

    def __init__(self, client, ignore=(), settings=None, seed=0, threads=1):
        """Validate the settings and precompute the beams' directions in the sensor frame."""
        self.settings = (settings or LidarSettings()).validate()
        self.client = client
        self.ignore = (ignore,) if isinstance(ignore, numbers.Integral) else tuple(ignore)
        self.threads = threads
        angles = self.settings.angles()
        self._cos, self._sin = np.cos(angles), np.sin(angles)
        self._rng = np.random.default_rng(seed)

    def scan(self, pose):
        """Return the Scan from a base at ``pose`` = (x, y, z, yaw) in the world."""
        settings = self.settings
        x, y, z, yaw = (float(v) for v in pose)
        mount_x, mount_y, mount_yaw = (float(v) for v in settings.mount)
        cos_yaw, sin_yaw = math.cos(yaw), math.sin(yaw)
        origin = np.array([x + cos_yaw * mount_x - sin_yaw * mount_y,
                           y + sin_yaw * mount_x + cos_yaw * mount_y, z + settings.height])
        heading = yaw + mount_yaw
        cos_h, sin_h = math.cos(heading), math.sin(heading)
        directions = np.column_stack([cos_h * self._cos - sin_h * self._sin,
                                      sin_h * self._cos + cos_h * self._sin,
                                      np.zeros(settings.beams)])
        ends = origin + settings.range_max * directions
        ranges, bodies = self._cast(origin, directions, ends)
        if settings.noise_std > 0.0:
            noise = self._rng.normal(0.0, settings.noise_std, settings.beams)
            hit = np.isfinite(ranges)
            ranges[hit] = np.maximum(ranges[hit] + noise[hit], 0.0)
        return Scan(settings, ranges.astype(np.float32), bodies, origin, heading)

    def _cast(self, origin, directions, ends):
        """Return each beam's distance to its first hit off the ignored bodies, and that body.

        The first batch starts at ``origin``; beams that hit an ignored body are
        re-cast from RECAST_STEP past the hit (if that is within range_max), at most
        MAX_RECASTS times.
        """
        beams = len(directions)
        ranges = np.full(beams, np.inf)
        bodies = np.full(beams, -1)
        todo = np.arange(beams)
        starts = np.zeros(beams)  # distance from the origin where each beam's ray starts
        range_max = self.settings.range_max
        for _ in range(MAX_RECASTS + 1):
            froms = origin + starts[:, None] * directions[todo]
            results = pb.rayTestBatch(froms.tolist(), ends[todo].tolist(),
                                      numThreads=self.threads, physicsClientId=self.client)
            hit_bodies = np.array([result[0] for result in results])
            fractions = np.array([result[2] for result in results])
            distances = starts + fractions * (range_max - starts)
            own = np.isin(hit_bodies, self.ignore)
            found = (hit_bodies >= 0) & ~own
            ranges[todo[found]] = distances[found]
            bodies[todo[found]] = hit_bodies[found]
            todo, starts = todo[own], distances[own] + RECAST_STEP
            todo, starts = todo[starts < range_max], starts[starts < range_max]
            if not todo.size:
                break
        return ranges, bodies


def laser_scan(scan, stamp):
    """Return the sensor_msgs/LaserScan of ``scan`` stamped ``stamp`` (builtin_interfaces/Time).

    ``scan_time`` = 1 / rate, ``time_increment`` = 0 (every beam at once), no intensities.
    """
    from sensor_msgs.msg import LaserScan

    settings = scan.settings
    message = LaserScan()
    message.header.stamp = stamp
    message.header.frame_id = settings.frame_id
    message.angle_min = settings.angle_min
    message.angle_max = settings.angle_max
    message.angle_increment = settings.angle_increment
    message.time_increment = 0.0
    message.scan_time = 1.0 / settings.rate
    message.range_min = float(settings.range_min)
    message.range_max = float(settings.range_max)
    message.ranges = array.array('f', np.ascontiguousarray(scan.ranges, np.float32).tobytes())
    return message


def mount_transform(settings, base_frame):
    """Return the static transform ``base_frame`` -> ``settings.frame_id`` (stamp 0).

    As ``sim_bridge.cdr.tf_message_cdr`` takes it: ``(0, 0, base_frame, frame_id,
    (mount x, mount y, height), (0, 0, sin(yaw / 2), cos(yaw / 2)))``.
    """
    mount_x, mount_y, mount_yaw = (float(v) for v in settings.mount)
    return (0, 0, base_frame, settings.frame_id, (mount_x, mount_y, float(settings.height)),
            (0.0, 0.0, math.sin(0.5 * mount_yaw), math.cos(0.5 * mount_yaw)))


def lidar_settings(items=(), **fields):
    """Return the validated LidarSettings of ``fields`` and ``FIELD=VALUE`` ``items``.

    Values in ``items`` are read as YAML (``mount=[0.1, 0, 0]``); only PARAMETER_FIELDS
    can be set there.  ValueError names a malformed item, an unknown field or a bad value.
    """
    for item in items:
        name, separator, value = item.partition('=')
        if not separator or name not in PARAMETER_FIELDS:
            raise ValueError(f'lidar settings are FIELD=VALUE with FIELD one of '
                             f'{", ".join(PARAMETER_FIELDS)}, got {item!r}')
        fields[name] = yaml.safe_load(value)
    if isinstance(fields.get('mount'), (list, array.array)):  # YAML, ROS double arrays
        fields['mount'] = tuple(fields['mount'])
    return LidarSettings(**fields).validate()


def laser_frame(robot):
    """Return the frame of ``robot``'s lidar: ``<robot>/laser``."""
    return f'{robot}/laser'


def _yaw(quaternion):
    """Return the yaw [rad] of quaternion [x, y, z, w]: atan2(2 (w z + x y), 1 - 2 (y^2 + z^2))."""
    x, y, z, w = (float(v) for v in quaternion)
    return math.atan2(2.0 * (w * z + x * y), 1.0 - 2.0 * (y * y + z * z))


class RobotLidars:
    """A Lidar on each of ``robots`` (default: all) of a ``sim_bridge.world.SimWorld``.

    Each scans the world's ray scene (``SimWorld.ray_scene``) in frame
    ``laser_frame(robot)``, blind to its own robot's proxy, its noise seeded with
    (``seed``, the robot's place in the scenario).  Scans are due every ``steps`` =
    physics_rate / ``settings.rate`` physics steps from step 0 (``rate_steps``:
    ScenarioError unless a whole number).  ValueError for an unknown robot.
    """

    def __init__(self, world, settings, robots=None, seed=0):
        """Validate, connect each chosen robot's Lidar to the world's ray scene."""
        settings = settings.validate()
        self.world = world
        self.steps = rate_steps(world.scenario.physics_rate, settings.rate, 'lidar rate',
                                'lidar')
        names = world.robot_names
        robots = names if robots is None else tuple(robots)
        unknown = [name for name in robots if name not in names]
        if unknown:
            raise ValueError(f'no robot {", ".join(map(repr, unknown))} for a lidar; '
                             f'the robots are {", ".join(names)}')
        client, proxies = world.ray_scene()
        self.lidars = {name: Lidar(client, proxies[name],
                                   dataclasses.replace(settings, frame_id=laser_frame(name)),
                                   seed=(seed, names.index(name)))
                       for name in robots}

    def scans(self):
        """Return [(robot, Scan)] due at the world's current physics step (else [])."""
        if self.world.steps % self.steps:
            return []
        self.world.ray_scene()  # brought to the current time
        scans = []
        for name, lidar in self.lidars.items():
            position, quaternion = self.world.robot_pose(name)
            scans.append((name, lidar.scan((*position.tolist(), _yaw(quaternion)))))
        return scans
