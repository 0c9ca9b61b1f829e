"""The shared ``main`` of this package's nodes (ros2/demos style)."""
import rclpy
from rclpy.executors import ExternalShutdownException


def run_node(node_class, name, args=None):
    """Spin ``node_class()`` until shutdown; return 1 if its configuration is invalid.

    A ``ValueError`` from the constructor is a configuration error: it is logged
    as fatal under ``name`` and the process exits with status 1.  Ctrl-C and an
    external shutdown end the spin cleanly (status 0).
    """
    rclpy.init(args=args)
    try:
        node = node_class()
    except ValueError as exc:
        rclpy.logging.get_logger(name).fatal(f'invalid configuration: {exc}')
        rclpy.try_shutdown()
        return 1
    try:
        rclpy.spin(node)
    except (KeyboardInterrupt, ExternalShutdownException):
        pass
    finally:
        node.destroy_node()
        rclpy.try_shutdown()
    return 0
