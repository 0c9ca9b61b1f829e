"""The private rclpy API this package relies on (``polyc2bf_ros.rclpy_private``) is there.

Run against the pinned rclpy: a new rclpy that moves or renames one of these names fails
here, naming it, before any node misbehaves.
"""
import inspect

import pytest
import rclpy
from rclpy.executors import SingleThreadedExecutor
from rclpy.lifecycle import LifecycleNode
from std_msgs.msg import Int32
from std_srvs.srv import SetBool

from polyc2bf_ros import rclpy_private

WAIT_SET_METHODS = ('clear_entities', 'add_subscription', 'add_timer', 'add_service',
                    'add_client', 'add_guard_condition', 'wait', 'get_ready_entities',
                    'destroy_when_not_in_use')


@pytest.fixture
def node():
    """Yield a node with a subscription, a timer, a service and a client on its own context."""
    context = rclpy.Context()
    rclpy.init(context=context)
    made = rclpy.create_node('private_api_probe', context=context)
    made.create_subscription(Int32, 'probe', lambda msg: None, 1)
    made.create_timer(10.0, lambda: None)
    made.create_service(SetBool, 'probe_service', lambda request, response: response)
    made.create_client(SetBool, 'probe_service')
    yield made
    made.destroy_node()
    rclpy.try_shutdown(context=context)


def test_the_wait_set_and_the_entity_handles_lean_executor_uses(node):
    """``WaitSet`` takes counts and a context, and has the methods the executors call."""
    wait_set = rclpy_private.WaitSet(1, 0, 1, 1, 1, 0, node.context.handle)
    missing = [name for name in WAIT_SET_METHODS if not hasattr(wait_set, name)]
    assert not missing, f'rclpy WaitSet lacks {missing}'
    wait_set.destroy_when_not_in_use()
    handles = {'subscription': (list(node.subscriptions)[0].handle, ('take_message', 'pointer')),
               'timer': (list(node.timers)[0].handle, ('call_timer', 'is_timer_ready', 'pointer')),
               'service': (list(node.services)[-1].handle, ('service_take_request', 'pointer')),
               'client': (list(node.clients)[0].handle, ('take_response', 'pointer'))}
    for kind, (handle, names) in handles.items():
        missing = [name for name in names if not hasattr(handle, name)]
        assert not missing, f'rclpy {kind} handle lacks {missing}'


def test_the_private_attributes_of_executor_subscription_and_lifecycle_node(node):
    """The attributes ``lean_executor`` and ``safety_filter_lifecycle`` read exist."""
    executor = SingleThreadedExecutor(context=node.context)
    try:
        missing = [a for a in rclpy_private.EXECUTOR_ATTRIBUTES if not hasattr(executor, a)]
        assert not missing, f'rclpy Executor lacks {missing}'
    finally:
        executor.shutdown()
    subscription = list(node.subscriptions)[0]
    missing = [a for a in rclpy_private.SUBSCRIPTION_ATTRIBUTES
               if not hasattr(subscription, a)]
    assert not missing, f'rclpy Subscription lacks {missing}'
    lifecycle = LifecycleNode('private_api_lifecycle', context=node.context)
    try:
        for name in rclpy_private.LIFECYCLE_ATTRIBUTES:
            assert callable(getattr(lifecycle, name).callback), f'{name}.callback'
    finally:
        lifecycle.destroy_node()


def test_logging_and_the_error_type():
    """The rcutils logging calls take what ``loop_log`` passes; RCLError is an exception."""
    assert issubclass(rclpy_private.RCLError, Exception)
    assert callable(rclpy_private.logger_is_enabled_for) and callable(rclpy_private.log)
    severity = rclpy.logging.LoggingSeverity.FATAL
    assert rclpy_private.logger_is_enabled_for('private_api_probe', severity) in (True, False)
    frame = inspect.currentframe()
    rclpy_private.log(rclpy.logging.LoggingSeverity.DEBUG, 'private_api_probe', 'probe',
                      frame.f_code.co_name, frame.f_code.co_filename, frame.f_lineno)
