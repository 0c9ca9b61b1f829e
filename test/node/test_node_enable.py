"""``~/enable``: false passes the nominal command through (loudly), true filters again."""
import pytest
from diagnostic_msgs.msg import DiagnosticStatus
from std_srvs.srv import SetBool

from node_harness import (
    Harness,
    latest_status,
    markers,
    node_log,
    odometry,
    RESEND,
    running_filter,
    twist,
    wall,
)

RATE = 50.0
# Waits end as soon as the output changes; this only turns a hang into a failure.
WAIT = 30.0


@pytest.mark.slow
def test_enable_service_switches_between_pass_through_and_filtering():
    """A wall 2 m ahead cuts 0.8 m/s from rest to a creep; disabled, it passes (with a WARN)."""
    # A starved node's stall-guard stop would make the disabled report an ERROR, not a WARN.
    params = {'model': 'unicycle', 'rate': RATE, 'stall_timeout': 10.0}
    with running_filter(params=params) as proc, Harness() as h:
        io = h.filter_io(proc)
        out, diagnostics = io.out, io.diagnostics
        nominal = twist(0.8, 0.1)

        def feed():
            io.odom.publish(odometry())
            io.cmd.publish(nominal)
            io.obstacles.publish(markers(wall([(2.0, -2.0), (2.0, 2.0)])))

        def filtered():
            return bool(out) and 0.0 < out[-1][1].linear.x < 0.2

        def passed_through():
            return bool(out) and out[-1][1] == nominal

        assert h.spin_until(filtered, WAIT, feed, 1.0 / RATE), (out[-3:], node_log(proc))
        response = h.call(SetBool, 'safety_filter/enable', SetBool.Request(data=False),
                          resend_after=RESEND)
        assert response.success and 'DISABLED' in response.message
        assert h.spin_until(passed_through, WAIT, feed, 1.0 / RATE)

        def reported_disabled():
            status, values = latest_status(diagnostics)
            return status is not None and values['enabled'] == 'false'

        assert h.spin_until(reported_disabled, WAIT, feed, 1.0 / RATE)
        status, _ = latest_status(diagnostics)
        assert status.level == DiagnosticStatus.WARN and 'DISABLED' in status.message
        assert 'DISABLED' in node_log(proc)

        response = h.call(SetBool, 'safety_filter/enable', SetBool.Request(data=True),
                          resend_after=RESEND)
        assert response.success
        assert h.spin_until(filtered, WAIT, feed, 1.0 / RATE)
