"""The shared ``main`` of this package's nodes (ros2/demos style)."""
import gc

import rclpy
from rclpy.executors import ExternalShutdownException

from polyc2bf_ros.lean_executor import LeanExecutor


def run_node(node_class, name, args=None):
    """Spin ``node_class()`` on a ``LeanExecutor`` until shutdown; return 1 on a bad configuration.

    A ``ValueError`` from the constructor is a configuration error: it is logged
    as fatal under ``name`` and the process exits with status 1.  Ctrl-C and an
    external shutdown end it cleanly (status 0), also during start-up.  Everything allocated
    during start-up (modules, the node) is frozen out of the garbage
    collector, so its full collections stay short while the node runs.
    """
    rclpy.init(args=args)
    try:
        node = node_class()
    except ValueError as exc:
        rclpy.logging.get_logger(name).fatal(f'invalid configuration: {exc}')
        rclpy.try_shutdown()
        return 1
    except (KeyboardInterrupt, ExternalShutdownException):  # Ctrl-C while starting up
        rclpy.try_shutdown()
        return 0
    executor = LeanExecutor()
    try:
        executor.add_node(node)
        gc.collect()
        gc.freeze()
        executor.spin()
    except (KeyboardInterrupt, ExternalShutdownException):
        pass
    finally:
        executor.shutdown()
        node.destroy_node()
        rclpy.try_shutdown()
    return 0
