"""The shared ``main`` of this package's nodes (ros2/demos style)."""
import gc
import signal

import rclpy
from rclpy.exceptions import ParameterException
from rclpy.executors import ExternalShutdownException

from polyc2bf_ros.lean_executor import LeanExecutor

# What a node's constructor raises for a bad configuration (rclpy's: out of range, wrong
# type, read-only).
CONFIGURATION_ERRORS = (ValueError, TypeError, ParameterException)


def configuration_error_text(exc):
    """Return ``exc`` as one line: ``invalid configuration: <reason>``."""
    reason = ' '.join(str(exc).split()) or type(exc).__name__
    return f'invalid configuration: {reason}'


def log_configuration_error(name, exc):
    """Log ``exc`` as one fatal line under logger ``name`` (no traceback)."""
    rclpy.logging.get_logger(name).fatal(configuration_error_text(exc))


def run_node(node_class, name, args=None):
    """Spin ``node_class()`` on a ``LeanExecutor`` until shutdown; return 1 on a bad configuration.

    Call it from the main thread of the process.  A ``ValueError``, ``TypeError``
    or rclpy ``ParameterException`` (out of range, wrong type, read-only) from the
    constructor is a configuration error: it is logged as one fatal line under
    ``name``, without a traceback, and the process exits with status 1.  Ctrl-C and
    an external shutdown end the node cleanly (status 0):

    - while starting up, Ctrl-C raises ``KeyboardInterrupt`` as usual;
    - while spinning it does not: rclpy's SIGINT handler shuts the context
      down and the executor stops before its next callback.  An interrupt
      raised inside a callback would break off whatever it was doing, and one
      raised inside rclpy's message conversion comes out as a ``RuntimeError``.
      A callback running at that moment can still fail in its next ROS call
      (a publish on the shut-down context raises ``RCLError``): an exception
      once the context is down is that, not a fault.

    Everything allocated during start-up (modules, the node) is frozen out of
    the garbage collector, so its full collections stay short while the node runs.
    """
    spinning = []

    def on_sigint(signum, frame):
        """Python's part of SIGINT (rclpy chains to it): interrupt only the start-up."""
        if not spinning:
            raise KeyboardInterrupt

    signal.signal(signal.SIGINT, on_sigint)  # before rclpy.init, so that rclpy chains to it
    rclpy.init(args=args)
    try:
        node = node_class()
    except CONFIGURATION_ERRORS as exc:
        log_configuration_error(name, exc)
        rclpy.try_shutdown()
        return 1
    except (KeyboardInterrupt, ExternalShutdownException):  # Ctrl-C while starting up
        rclpy.try_shutdown()
        return 0
    executor = None
    try:
        executor = LeanExecutor()  # Ctrl-C may still arrive here, while starting up
        executor.add_node(node)
        gc.collect()
        gc.freeze()
        spinning.append(True)
        executor.spin()
    except (KeyboardInterrupt, ExternalShutdownException):
        pass
    except Exception:
        if rclpy.ok():
            raise
    finally:
        if executor is not None:
            executor.shutdown()
        node.destroy_node()
        rclpy.try_shutdown()
    return 0
