"""One source for the Crazyflie's constants: the shipped URDF carries crazyflie.py's numbers.

``polyc2bf_ros.core.models.crazyflie`` is what the filter's quadrotor model uses, so it is
the source; ``sim_bridge/assets/crazyflie21.urdf`` (parsed here with ElementTree)
must match it, and so must what PyBullet makes of the URDF when the world loads it.
"""
import math
import xml.etree.ElementTree as ET

import numpy as np
import pybullet as pb
import pytest

from polyc2bf_ros.core.models import crazyflie as cf
from sim_bridge.plants import CRAZYFLIE_HALF_HEIGHT, CRAZYFLIE_URDF
from sim_bridge.robots import ROBOT_TYPES
from sim_bridge.scenario import scenario_from_dict
from sim_bridge.world import SimWorld

REL = 1e-9  # numbers written in full in the URDF
POSITION_ATOL = 1e-7  # m: rotor coordinates are written to 10 nm (arm / sqrt 2 is irrational)


@pytest.fixture(scope='module')
def link():
    """Return the URDF's one link element."""
    links = ET.parse(CRAZYFLIE_URDF).getroot().findall('link')
    assert len(links) == 1, 'the Crazyflie is one rigid link (thrusts are external forces)'
    return links[0]


def _floats(text):
    return np.array([float(v) for v in text.split()])


def _origin(element):
    """Return (xyz, rpy) of an element's <origin> (zeros when absent)."""
    origin = element.find('origin')
    if origin is None:
        return np.zeros(3), np.zeros(3)
    return _floats(origin.get('xyz', '0 0 0')), _floats(origin.get('rpy', '0 0 0'))


def _visuals(link, shape):
    """Return the link's visuals whose geometry is ``shape`` (cylinder, box), in file order."""
    return [v for v in link.findall('visual') if v.find(f'geometry/{shape}') is not None]


def test_urdf_mass_is_the_module_mass(link):
    """<mass> = MASS."""
    mass = float(link.find('inertial/mass').get('value'))
    assert mass == pytest.approx(cf.MASS, rel=REL)


def test_urdf_inertia_is_the_module_inertia_about_the_link_origin(link):
    """<inertia> = INERTIA (diagonal and products), about a centre of mass at the origin."""
    inertial = link.find('inertial')
    inertia = inertial.find('inertia')
    diagonal = [float(inertia.get(k)) for k in ('ixx', 'iyy', 'izz')]
    np.testing.assert_allclose(diagonal, np.diag(cf.INERTIA), rtol=REL, atol=0.0)
    products = [float(inertia.get(k)) for k in ('ixy', 'ixz', 'iyz')]
    module_products = cf.INERTIA[np.triu_indices(3, 1)]
    np.testing.assert_array_equal(products, module_products)
    # The rotor positions are relative to the centre of mass: it must be the link origin.
    xyz, rpy = _origin(inertial)
    np.testing.assert_array_equal(xyz, 0.0)
    np.testing.assert_array_equal(rpy, 0.0)


def test_urdf_rotor_discs_sit_at_the_module_rotor_positions(link):
    """Four rotor discs, in ROTOR_POSITIONS' numbering, at arm length from the centre."""
    discs = _visuals(link, 'cylinder')
    assert len(discs) == len(cf.ROTOR_POSITIONS) == 4
    centres = np.array([_origin(d)[0] for d in discs])
    np.testing.assert_allclose(centres[:, :2], cf.ROTOR_POSITIONS[:, :2], rtol=0.0,
                               atol=POSITION_ATOL)
    np.testing.assert_allclose(np.hypot(centres[:, 0], centres[:, 1]), cf.ARM, rtol=1e-6)
    # Drawn just above the thrust plane z = 0, within the collision cylinder.
    assert np.all(np.abs(centres[:, 2] - cf.ROTOR_POSITIONS[:, 2]) < CRAZYFLIE_HALF_HEIGHT)
    # The front rotors (x > 0) are the red ones.
    front = [d.find('material').get('name') == 'front_rotor' for d in discs]
    assert front == list(cf.ROTOR_POSITIONS[:, 0] > 0)


def test_urdf_board_arms_join_opposite_rotors(link):
    """The two diagonal board arms are 2 arm long, at +-45 degrees (the X layout)."""
    arms = _visuals(link, 'box')
    assert len(arms) == 2
    lengths = [_floats(a.find('geometry/box').get('size'))[0] for a in arms]
    np.testing.assert_allclose(lengths, 2.0 * cf.ARM, rtol=REL)
    yaws = sorted(_origin(a)[1][2] for a in arms)
    np.testing.assert_allclose(yaws, [-math.pi / 4, math.pi / 4], atol=1e-6)
    np.testing.assert_allclose(
        np.abs(np.arctan2(cf.ROTOR_POSITIONS[:, 1], cf.ROTOR_POSITIONS[:, 0])) % (math.pi / 2),
        math.pi / 4, atol=1e-12)


def test_urdf_collision_cylinder_is_the_body_radius_and_height(link):
    """Collision radius = BODY_RADIUS (the filter's and the scenario's robot radius)."""
    (collision,) = link.findall('collision')
    cylinder = collision.find('geometry/cylinder')
    radius, length = float(cylinder.get('radius')), float(cylinder.get('length'))
    assert radius == pytest.approx(cf.BODY_RADIUS, rel=REL)
    assert ROBOT_TYPES['crazyflie'].radius == cf.BODY_RADIUS
    assert length / 2.0 == pytest.approx(CRAZYFLIE_HALF_HEIGHT, rel=REL)
    xyz, _ = _origin(collision)
    np.testing.assert_array_equal(xyz, 0.0)
    # Every rotor disc lies inside the collision cylinder.
    disc_radii = [float(d.find('geometry/cylinder').get('radius'))
                  for d in _visuals(link, 'cylinder')]
    assert cf.ARM + max(disc_radii) <= radius


def test_pybullet_loads_the_module_mass_and_inertia():
    """DIRECT mode, loaded as SimWorld loads it: getDynamicsInfo reports crazyflie.py's numbers."""
    client = pb.connect(pb.DIRECT)
    try:
        body = pb.loadURDF(str(CRAZYFLIE_URDF), flags=pb.URDF_USE_INERTIA_FROM_FILE,
                           physicsClientId=client)
        info = pb.getDynamicsInfo(body, -1, physicsClientId=client)
        mass, inertia_diagonal = info[0], info[2]
        local_position, local_orientation = info[3], info[4]
    finally:
        pb.disconnect(physicsClientId=client)
    assert mass == pytest.approx(cf.MASS, rel=REL)
    np.testing.assert_allclose(inertia_diagonal, np.diag(cf.INERTIA), rtol=1e-6, atol=0.0)
    np.testing.assert_allclose(local_position, 0.0, atol=1e-12)
    np.testing.assert_allclose(local_orientation, [0.0, 0.0, 0.0, 1.0], atol=1e-12)


def test_simulated_crazyflie_answers_a_wrench_with_the_module_mass_and_inertia():
    """One physics step from rest: dv_z = (T / m - g) dt = 0 at T = m g, dw = I^-1 tau dt.

    The body SimWorld builds, driven through the mixer: a wrong mass sinks or lifts it,
    a wrong inertia or rotor position turns it at another rate.
    """
    scenario = scenario_from_dict({
        'name': 'probe', 'duration': 1.0,
        'robots': [{'name': 'cf', 'type': 'crazyflie', 'start': [0.0, 0.0, 1.0, 0.0],
                    'goal': [0.0, 0.0, 1.0]}]})
    torque = np.array([2e-5, -3e-5, 1e-6])
    with SimWorld(scenario) as world:
        world.set_command('cf', np.concatenate([[cf.MASS * cf.GRAVITY], torque]), 'wrench')
        world.step()
        state = world.robot_state('cf')
        dt = world.dt
    np.testing.assert_allclose(state[3:6], 0.0, atol=1e-12)
    np.testing.assert_allclose(state[9:12], np.linalg.solve(cf.INERTIA, torque) * dt,
                               rtol=1e-6, atol=0.0)
