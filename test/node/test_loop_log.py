"""``LoopLogger``: rclpy's throttle semantics per call site, output through rcutils."""
import os
import subprocess
import sys
from pathlib import Path

from rclpy.logging import get_logger, LoggingSeverity, set_logger_level

from polyc2bf_ros.loop_log import LoopLogger

REPO = Path(__file__).resolve().parents[2]


class FakeClock:
    """A steady clock the test sets."""

    def __init__(self):
        """Start at 100 s."""
        self.now = 100.0

    def __call__(self):
        """Return the set time."""
        return self.now


def test_throttle_passes_the_first_then_none_for_the_window_per_site():
    """As rclpy's throttle: the first message passes, then none for ``throttle_s``, per site."""
    clock = FakeClock()
    log = LoopLogger(get_logger('test_loop_log_throttle'), clock=clock)

    def site_a():
        return log.error('a', throttle_s=1.0)

    def site_b():
        return log.error('b', throttle_s=1.0)

    assert site_a() and not site_a()
    assert site_b()  # another call site has its own window
    clock.now += 0.999
    assert not site_a()
    clock.now += 0.002
    assert site_a() and not site_a()
    assert all(log.error('unthrottled') for _ in range(3))


def test_a_severity_below_the_logger_level_is_not_emitted():
    """The logger's level is rcutils' (``set_logger_level``), as for rclpy's own calls."""
    name = 'test_loop_log_level'
    set_logger_level(name, LoggingSeverity.ERROR)
    log = LoopLogger(get_logger(name))
    assert not log.warning('below the level') and not log.info('below the level')
    assert log.error('at the level')


def test_messages_reach_the_console_with_name_severity_and_caller():
    """A fresh process: five throttled calls print one line, naming node, severity, caller."""
    code = ('import rclpy\n'
            'from polyc2bf_ros.loop_log import LoopLogger\n'
            'rclpy.init()\n'
            'node = rclpy.create_node("loop_log_probe")\n'
            'log = LoopLogger(node.get_logger())\n'
            'def report():\n'
            '    for _ in range(5):\n'
            '        log.warning("obstacles stale: braking", throttle_s=60.0)\n'
            'report()\n'
            'rclpy.try_shutdown()\n')
    env = dict(os.environ, RCUTILS_CONSOLE_OUTPUT_FORMAT='[{severity}] [{name}] {function_name}: '
               '{message}')
    result = subprocess.run([sys.executable, '-c', code], cwd=REPO, env=env, text=True,
                            capture_output=True, timeout=60)
    assert result.returncode == 0, result.stderr
    lines = [line for line in result.stderr.splitlines() if 'obstacles stale' in line]
    assert lines == ['[WARN] [loop_log_probe] report: obstacles stale: braking']
