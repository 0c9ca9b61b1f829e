"""Evasion (``SafetyFilter._evade``, design.md 3.10): held inputs that keep clear of what moves."""
import numpy as np
import pytest
from hypothesis import given, settings, strategies as st

from polyc2bf_ros.core.models import make_model
from polyc2bf_ros.core.obstacles.obstacle_set import Obstacle, ObstacleSet
from polyc2bf_ros.core.safety_filter import FilterConfig, FilterStatus, SafetyFilter
from strategies import examples

PERIOD = 0.01
RADIUS = 0.2
SIDE = 0.5  # m: half the side of the square coming at the robot


def _filter(horizon, model=None, commit=False, max_speed=0.0):
    return SafetyFilter(model or make_model('unicycle', offset_l=0.01, max_accel=2.0),
                        FilterConfig(barrier='polyc2bf_horizon', robot_radius=RADIUS,
                                     gamma=5.0, control_period=PERIOD,
                                     evasion_horizon=horizon, evasion_commit=commit,
                                     evasion_max_speed=max_speed))


def _square(centre, velocity, error=0.0):
    cx, cy = centre
    polygon = np.array([[cx - SIDE, cy - SIDE], [cx + SIDE, cy - SIDE],
                        [cx + SIDE, cy + SIDE], [cx - SIDE, cy + SIDE]])
    return Obstacle(polygon=polygon, velocity=np.array([*velocity, 0.0]),
                    velocity_error=error)


def _gap(position, centre):
    """Distance from the robot's disc to the square (negative: overlap, roughly)."""
    offset = np.abs(np.asarray(position) - centre) - SIDE
    return float(np.linalg.norm(np.maximum(offset, 0.0)) + min(offset.max(), 0.0)) - RADIUS


def _crossing(horizon, speed, seconds=4.0, start=((0.0, 2.0), 0.0, 'stay'), commit=False,
              error=0.0, max_speed=0.0, speeds=None):
    """Run a unicycle past a square crossing from the side at ``speed``.

    ``start``: the square's centre, the robot's speed along +x from the origin, and its
    nominal: 'stay' (the brake) or 'keep' (no acceleration); ``error``: the square's own
    velocity bound (an untrusted scan track); ``max_speed``: ``evasion_max_speed``;
    ``speeds``: a list to which the robot's speed is appended each period.  Return (smallest
    gap, statuses, the robot's speed toward the square at the closest approach).
    """
    model = make_model('unicycle', offset_l=0.01, max_accel=2.0)
    filt = _filter(horizon, model, commit, max_speed)
    centre, robot_speed, nominal = start
    state = np.array([0.0, 0.0, 0.0, robot_speed, 0.0])
    centre, velocity = np.array(centre), np.array([0.0, -speed])
    gaps, statuses, toward = [], [], []
    for _ in range(round(seconds / PERIOD)):
        u_nom = (model.clip_input(model.braking_input(state)) if nominal == 'stay'
                 else np.zeros(2))
        u, info = filt.step(state, ObstacleSet.from_obstacles([_square(centre, velocity, error)]),
                            u_nom)
        statuses.append(info.status)
        middle = state + 0.5 * PERIOD * model.state_derivative(state, u)
        state = state + PERIOD * model.state_derivative(middle, u)
        centre = centre + PERIOD * velocity
        if speeds is not None:
            speeds.append(abs(state[3]))
        gaps.append(_gap(state[:2], centre))
        away = centre - state[:2]
        toward.append(state[3] * np.array([np.cos(state[2]), np.sin(state[2])])
                      @ away / np.linalg.norm(away))
    closest = int(np.argmin(gaps))
    return gaps[closest], statuses, toward[closest]


@pytest.mark.parametrize('speed', [0.6, 1.0])
def test_a_robot_steps_out_of_the_way_of_a_square_crossing_its_place(speed):
    """Without evasion the robot brakes where it stands and is run over; with it, it leaves.

    And it never closes on the square at its closest approach (what the dynamic suite calls
    an at-fault contact).
    """
    gap, statuses, _ = _crossing(0.0, speed)
    assert gap < 0.0 and FilterStatus.EVADE not in statuses
    gap, statuses, toward = _crossing(1.0, speed)
    assert gap > 0.0, gap
    assert FilterStatus.EVADE in statuses
    assert toward <= 0.05


def test_a_committed_evasion_drives_on_past_a_square_that_would_catch_it_braking():
    """``evasion_commit``: the way out is ahead, across the braking check's moving test.

    The robot drives at 1 m/s along +x; a square crossing at 1.5 m/s sweeps x in [0, 1],
    where braking stops the robot (at x = 0.25) and where backing up cannot leave in time.
    Speeding up clears the sweep first, yet its braking path closes on the square, which
    the braking check refuses: without commitment the robot brakes in the square's way.
    Committed, the evasion takes it because its whole look ahead keeps clear.
    """
    start = ((0.5, 2.0), 1.0, 'keep')
    for horizon in (0.0, 1.0):
        gap, statuses, _ = _crossing(horizon, 1.5, 2.5, start)
        assert gap < 0.0
    gap, statuses, _ = _crossing(1.0, 1.5, 2.5, start, commit=True)
    assert gap > 0.0, gap
    assert FilterStatus.EVADE in statuses


def test_an_evasion_at_its_speed_limit_does_not_speed_the_robot_up():
    """``evasion_max_speed``: at 1 m/s, the crossing above is evaded without going faster.

    Unlimited, the committed evasion speeds the robot up past the square (above 1.3 m/s).
    Limited to the 1 m/s it drives, no evasion step adds speed, and the square does not
    reach it while it closes on it.
    """
    start = ((0.5, 2.0), 1.0, 'keep')
    unlimited = []
    _crossing(1.0, 1.5, 2.5, start, commit=True, speeds=unlimited)
    assert max(unlimited) > 1.3
    limited = []
    gap, statuses, toward = _crossing(1.0, 1.5, 2.5, start, commit=True, max_speed=1.0,
                                      speeds=limited)
    evading = [speed for speed, status in zip(limited, statuses) if status == FilterStatus.EVADE]
    assert evading and max(evading) < 1.01, max(evading)  # a turn may add a few mm/s
    assert gap > 0.0 or toward <= 0.05, (gap, toward)


def test_no_evasion_is_committed_past_an_obstacle_whose_velocity_is_not_known():
    """The same square as an untrusted scan track (its own 2 m/s bound): no wager on it.

    A committed input trusts the square's stated velocity; with its own bound the filter
    does exactly what it does without commitment.
    """
    start = ((0.5, 2.0), 1.0, 'keep')
    committed = _crossing(1.0, 1.5, 2.5, start, commit=True, error=2.0)
    plain = _crossing(1.0, 1.5, 2.5, start, commit=False, error=2.0)
    assert committed[0] == plain[0] and committed[1] == plain[1]
    assert committed[0] != _crossing(1.0, 1.5, 2.5, start, commit=True)[0]


def _step_beside(centre, velocity, acceleration, horizon=1.0):
    """Return (input, status) of one step of a standing robot beside a moving square."""
    square = _square(centre, velocity)
    square = Obstacle(polygon=square.polygon, velocity=square.velocity,
                      acceleration=np.array(acceleration, dtype=float))
    state = np.zeros(5)
    u, info = _filter(horizon).step(state, ObstacleSet.from_obstacles([square]), np.zeros(2))
    return u, info.status


def test_the_look_ahead_follows_a_squares_acceleration():
    """A square 1.3 m off, drifting in at 0.3 m/s but speeding up at 2 m/s^2.

    At constant velocity it stops 0.7 m short of the robot within the look ahead's second;
    speeding up it reaches the robot (1 m more), so the robot evades, backing away.
    """
    u, status = _step_beside((0.0, 1.8), (0.0, -0.3), (0.0, 0.0))
    assert status != FilterStatus.EVADE
    u, status = _step_beside((0.0, 1.8), (0.0, -0.3), (0.0, -2.0))
    assert status == FilterStatus.EVADE and u[0] != 0.0


@settings(max_examples=examples(60), deadline=None)
@given(x=st.floats(-3.0, 3.0), y=st.floats(-3.0, 3.0), heading=st.floats(-3.1, 3.1),
       speed=st.floats(-1.0, 2.0), nominal=st.floats(-2.0, 2.0))
def test_standing_obstacles_never_start_an_evasion(x, y, heading, speed, nominal):
    """Only moving parts start an evasion: among standing ones the filter is unchanged."""
    wall = Obstacle(polygon=np.array([[1.0, -2.0], [1.2, -2.0], [1.2, 2.0], [1.0, 2.0]]))
    box = Obstacle(polygon=np.array([[-1.5, -1.5], [-0.8, -1.5], [-0.8, -0.8], [-1.5, -0.8]]))
    obstacles = ObstacleSet.from_obstacles([wall, box])
    state = np.array([x, y, heading, speed, 0.0])
    with_evasion, info = _filter(1.0).step(state, obstacles, np.array([nominal, 0.0]))
    without, _ = _filter(0.0).step(state, obstacles, np.array([nominal, 0.0]))
    assert info.status != FilterStatus.EVADE
    np.testing.assert_array_equal(with_evasion, without)


@pytest.mark.parametrize('name', ['evasion_horizon', 'evasion_max_speed'])
def test_evasion_settings_must_be_finite_and_non_negative(name):
    """A negative or infinite look ahead or speed limit is refused by name."""
    for value in (-1.0, float('inf'), float('nan')):
        with pytest.raises(ValueError, match=name):
            FilterConfig(**{name: value}).validate()


@settings(max_examples=examples(40), deadline=None)
@given(name=st.sampled_from(['unicycle', 'point_mass_2d']), seed=st.integers(0, 2 ** 32 - 1))
def test_held_path_follows_the_dynamics(name, seed):
    """``RobotModel.held_path`` agrees with a fine integration of x_dot = f(x) + g(x) u.

    The rows are the reference point's position and velocity every 0.05 s for 1 s; the
    returned state is the one at the last row.  The midpoint rule at 0.05 s strays a few mm
    over the second, turning at up to 4 rad/s^2: 5 mm is allowed.
    """
    rng = np.random.default_rng(seed)
    model = make_model(name)
    if name == 'unicycle':
        state = np.array([*rng.uniform(-3, 3, 2), rng.uniform(-3.1, 3.1),
                          rng.uniform(-1.5, 1.5), rng.uniform(-2.0, 2.0)])
    else:
        state = np.concatenate([rng.uniform(-3, 3, 2), rng.uniform(-1.5, 1.5, 2)])
    u = rng.uniform(model.input_lower, model.input_upper)
    path, end = model.held_path(state, u, 0.05, 20)
    fine, dt = state.copy(), 1e-4
    for k in range(20):
        for _ in range(500):
            middle = fine + 0.5 * dt * model.state_derivative(fine, u)
            fine = fine + dt * model.state_derivative(middle, u)
        ref = model.reference(fine)
        np.testing.assert_allclose(path[k], np.concatenate((ref.position, ref.velocity)),
                                   atol=5e-3)
    np.testing.assert_allclose(end, fine, atol=5e-3)
