"""The one door to rclpy's private API (rclpy 7.1, ROS 2 Jazzy, as pinned).

Every use of an rclpy name that is not public goes through here, so a new rclpy breaks
one module, and ``test/node/test_rclpy_private.py`` fails loudly, naming what moved:

- ``WaitSet``: the rcl wait set (``rclpy_implementation.WaitSet``), filled with entity
  handles and read with ``get_ready_entities``, as ``rclpy.executors`` and
  ``rclpy.wait_for_message`` use it (``lean_executor``, ``sim_bridge.inbox.Inbox``);
  the handles' ``take_message``, ``call_timer``, ``is_timer_ready``,
  ``service_take_request``, ``take_response`` and ``pointer`` belong with it;
- ``logger_is_enabled_for`` / ``log``: rcutils logging without rclpy's caller lookup,
  which reads source on every call (``loop_log``);
- ``RCLError``: what a refused lifecycle transition raises (``safety_filter_lifecycle``);
- ``EXECUTOR_ATTRIBUTES`` and ``SUBSCRIPTION_ATTRIBUTES``: the private attributes of
  ``rclpy.executors.Executor`` (``_guard``, ``_sigint_gc``, ``_is_shutdown``) and of
  ``rclpy.subscription.Subscription`` (``_callback_type``) that ``lean_executor`` reads,
  and ``LIFECYCLE_ATTRIBUTES``, the ``_service_change_state`` of ``rclpy``'s lifecycle
  node that ``safety_filter_lifecycle`` wraps; listed for the test, which checks them on
  live objects.
"""
from rclpy.impl.implementation_singleton import rclpy_implementation as _implementation

WaitSet = _implementation.WaitSet
RCLError = _implementation.RCLError
logger_is_enabled_for = _implementation.rclpy_logging_logger_is_enabled_for
log = _implementation.rclpy_logging_rcutils_log

EXECUTOR_ATTRIBUTES = ('_guard', '_sigint_gc', '_is_shutdown', '_context')
SUBSCRIPTION_ATTRIBUTES = ('_callback_type',)
LIFECYCLE_ATTRIBUTES = ('_service_change_state',)
