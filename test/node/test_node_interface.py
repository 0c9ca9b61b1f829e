"""Names, stamps, QoS and parameters: remapping, header copy, late joiners, refusals."""
import pytest
from diagnostic_msgs.msg import DiagnosticArray
from geometry_msgs.msg import Twist, TwistStamped
from nav_msgs.msg import Odometry
from rcl_interfaces.msg import Parameter as ParameterMsg
from rcl_interfaces.srv import DescribeParameters, GetParameters, SetParameters
from rclpy.parameter import Parameter
from rclpy.qos import QoSProfile, ReliabilityPolicy
from visualization_msgs.msg import MarkerArray

from node_harness import (
    Harness,
    LATCHED,
    latest_status,
    markers,
    node_log,
    odometry,
    RESEND,
    running_filter,
    twist,
    wall,
)

BEST_EFFORT = QoSProfile(depth=1, reliability=ReliabilityPolicy.BEST_EFFORT)

NAMESPACE = '/robot7'
RATE = 100.0


@pytest.fixture(scope='module')
def stamped_filter():
    """Run a command-triggered, stamped filter in /robot7 reading ``nominal_cmd``."""
    params = {'model': 'point_mass_2d', 'stamped': True, 'trigger': 'command', 'rate': RATE}
    with running_filter('-r', f'__ns:={NAMESPACE}', '-r', 'cmd_vel_in:=nominal_cmd',
                        params=params) as proc, Harness(NAMESPACE) as h:
        yield proc, h


def _set(h, **values):
    request = SetParameters.Request(parameters=[
        Parameter(name, value=value).to_parameter_msg() for name, value in values.items()])
    return h.call(SetParameters, 'safety_filter/set_parameters', request,
                  resend_after=RESEND).results


def _get(h, *names):
    response = h.call(GetParameters, 'safety_filter/get_parameters',
                      GetParameters.Request(names=list(names)), resend_after=RESEND)
    return [Parameter.from_parameter_msg(ParameterMsg(name=n, value=v)).value
            for n, v in zip(names, response.values)]


@pytest.mark.slow
def test_namespace_remap_and_header_copy(stamped_filter):
    """Input on /robot7/nominal_cmd -> output on /robot7/cmd_vel_out with the same header."""
    proc, h = stamped_filter
    io = h.filter_io(proc, TwistStamped, 'nominal_cmd')
    nominal = TwistStamped()
    nominal.header.frame_id = 'base_link'
    nominal.header.stamp.sec, nominal.header.stamp.nanosec = 123, 456789
    nominal.twist.linear.x = 0.3
    io.obstacles.publish(markers())

    def feed():
        io.odom.publish(odometry(v=0.3))
        io.cmd.publish(nominal)

    def answered():
        return any(m.twist.linear.x > 0.2 for _, m in io.out)

    assert h.spin_until(answered, 15.0, feed, 0.01), node_log(proc)
    answer = next(m for _, m in io.out if m.twist.linear.x > 0.2)
    assert answer.header == nominal.header
    assert answer.twist.linear.x == pytest.approx(0.3)


@pytest.mark.slow
def test_best_effort_odometry_is_accepted(stamped_filter):
    """Odometry from a best-effort publisher keeps the filter answering (not stopping).

    With trigger:=command a stale odometry answers with a stop (0 m/s); a fresh
    one returns the reachable nominal 0.25 m/s unchanged.
    """
    proc, h = stamped_filter
    io = h.filter_io(proc, TwistStamped, 'nominal_cmd', odom_qos=BEST_EFFORT)
    out = io.out
    io.obstacles.publish(markers())
    nominal = TwistStamped()
    nominal.header.frame_id = 'best_effort'
    nominal.twist.linear.x = 0.25

    def feed():
        io.odom.publish(odometry(v=0.25))
        io.cmd.publish(nominal)

    def answered():
        return any(m.header.frame_id == 'best_effort' and abs(m.twist.linear.x - 0.25) < 1e-9
                   for _, m in out)

    assert h.spin_until(answered, 15.0, feed, 0.01), (
        [(m.header.frame_id, m.twist.linear.x) for _, m in out[-3:]], node_log(proc))


@pytest.mark.slow
def test_obstacles_published_before_the_filter_starts_reach_it():
    """A latched obstacle map published before the filter exists is in use once it runs."""
    with Harness() as h:
        obstacles_pub = h.publisher(MarkerArray, 'obstacles', LATCHED)
        obstacles_pub.publish(markers(wall([(2.0, -1.0), (2.0, 1.0)])))
        diagnostics = h.collect(DiagnosticArray, '/diagnostics')
        with running_filter(params={'model': 'unicycle', 'obstacles_timeout': 0.0}) as proc:
            odom_pub = h.publisher(Odometry, 'odom')
            cmd_pub = h.publisher(Twist, 'cmd_vel_in')
            assert h.wait_for_subscribers(odom_pub, cmd_pub), node_log(proc)

            def feed():
                odom_pub.publish(odometry())
                cmd_pub.publish(twist(0.2))

            def in_use():
                values = latest_status(diagnostics)[1]
                return values.get('obstacles_in_use') == '1' and values['stale_inputs'] == 'none'

            assert h.spin_until(in_use, 15.0, feed, 0.02), (latest_status(diagnostics),
                                                             node_log(proc))


@pytest.mark.slow
@pytest.mark.parametrize('values, reason', [
    ({'rate': 5000.0}, 'range'),
    ({'cylinder_sides': 2}, 'range'),
    ({'odom_timeout': 0.005}, 'control period'),
    ({'filter.gamma': 0.0}, 'gamma'),
    ({'filter.barrier': 'cubes'}, 'barrier'),
    ({'model': 'quadrotor'}, 'read-only'),
    ({'rate': 2.0}, 'odom_timeout'),
])
def test_bad_parameter_values_are_refused_with_a_reason(stamped_filter, values, reason):
    """Out-of-range, inconsistent or read-only sets fail with a reason; old values stay."""
    _, h = stamped_filter
    before = _get(h, *values)
    results = _set(h, **values)
    assert not any(r.successful for r in results)
    assert any(reason in r.reason for r in results), [r.reason for r in results]
    assert _get(h, *values) == before


@pytest.mark.slow
def test_good_values_are_applied_and_parameters_are_described(stamped_filter):
    """A valid change is accepted; descriptors carry descriptions and ranges."""
    _, h = stamped_filter
    assert all(r.successful for r in _set(h, **{'filter.gamma': 2.5, 'rate': 200.0}))
    assert _get(h, 'filter.gamma', 'rate') == [2.5, 200.0]
    assert all(r.successful for r in _set(h, rate=RATE))
    response = h.call(DescribeParameters, 'safety_filter/describe_parameters',
                      DescribeParameters.Request(names=['rate', 'model', 'cylinder_sides']),
                      resend_after=RESEND)
    rate, model, sides = response.descriptors
    assert rate.description and rate.floating_point_range[0].to_value == 2000.0
    assert model.read_only and 'point_mass_2d' in model.description
    assert sides.integer_range[0].from_value == 3
