"""``LeanExecutor`` over real rclpy/DDS: timers, topics, services, parameters, shutdown."""
import signal
import subprocess
import sys
import threading
import time

import pytest
import rclpy
from rcl_interfaces.msg import FloatingPointRange, ParameterDescriptor, SetParametersResult
from rclpy.clock import Clock, ClockType
from rclpy.event_handler import SubscriptionEventCallbacks
from rclpy.executors import ExternalShutdownException
from rclpy.parameter import Parameter
from rclpy.parameter_client import AsyncParameterClient
from rclpy.qos import QoSProfile, ReliabilityPolicy
from std_msgs.msg import Int32
from std_srvs.srv import SetBool

from node_harness import Harness, node_log, REPO, running_filter
from polyc2bf_ros.lean_executor import LeanExecutor, WAITABLE_PERIOD

RELIABLE = QoSProfile(depth=100, reliability=ReliabilityPolicy.RELIABLE)


@pytest.fixture
def context():
    """Yield a private rclpy context and shut it down afterwards."""
    ctx = rclpy.Context()
    rclpy.init(context=ctx)
    yield ctx
    rclpy.try_shutdown(context=ctx)


@pytest.fixture
def executor(context):
    """Yield a ``LeanExecutor`` on the private context."""
    lean = LeanExecutor(context=context)
    yield lean
    lean.shutdown()


def _node(context, name):
    return rclpy.create_node(name, context=context)


def _spin_until(executor, predicate, timeout=10.0):
    end = time.monotonic() + timeout
    while not predicate() and time.monotonic() < end:
        executor.spin_once(timeout_sec=0.05)
    return predicate()


def _spin_for(executor, seconds):
    end = time.monotonic() + seconds
    while time.monotonic() < end:
        executor.spin_once(timeout_sec=max(end - time.monotonic(), 0.0))


def _wait_for(predicate, timeout):
    """Sleep-poll until ``predicate()`` or ``timeout`` s (a hang detector, not a bound)."""
    end = time.monotonic() + timeout
    while not predicate() and time.monotonic() < end:
        time.sleep(0.01)
    return predicate()


def test_steady_timers_fire_at_their_rate_and_follow_period_changes(context, executor):
    """100 Hz, then 20 Hz after a period change: never early, whatever the load.

    rcl keeps a steady timer's due times on a grid: the first is ``t_created + T``, each
    call moves it on by T, and a late call skips the periods it missed instead of
    catching up.  So the i-th call (from 1) runs at or after ``t_created + i T``.  Once a
    new period is in effect, call a + 1 is due no earlier than call a ran (after call
    a - 1 returned: one callback at a time), and each later call T_new after it, so
    calls p < b run at least ``(b - p - 2) T_new`` apart.  Both hold on a starved
    machine; how many calls a second gets does not, so it is not asserted.
    """
    node = _node(context, 'timers')
    executor.add_node(node)
    calls = []
    created = time.monotonic()
    timer = node.create_timer(0.01, lambda: calls.append(time.monotonic()),
                              clock=Clock(clock_type=ClockType.STEADY_TIME))
    spinner = threading.Thread(target=executor.spin)
    spinner.start()
    try:
        assert _wait_for(lambda: len(calls) >= 50, 60.0), len(calls)
        timer.timer_period_ns = 50_000_000
        changed = len(calls)   # a call running now may have been due on the old period
        assert _wait_for(lambda: len(calls) >= changed + 12, 60.0), len(calls) - changed
    finally:
        executor.shutdown()
        spinner.join(5.0)
    assert not spinner.is_alive(), 'spin() did not return after shutdown()'
    fast = calls[:changed]
    early = [(i, t - created) for i, t in enumerate(fast, 1) if t < created + i * 0.01 - 1e-6]
    assert not early, f'calls ahead of the 10 ms grid (index, s after creation): {early[:5]}'
    # Calls from `changed` on: the first of them is call p = a - 1 above, the next one a.
    slow = calls[changed:]
    gaps = [round(b - a, 4) for a, b in zip(slow, slow[1:])]
    assert slow[-1] - slow[0] >= (len(slow) - 3) * 0.05 - 1e-6, gaps


def test_subscriptions_take_every_queued_message_in_order(context, executor):
    """200 messages published before anyone spins all arrive, in order, with message info."""
    node = _node(context, 'listener')
    executor.add_node(node)
    received, infos = [], []

    def with_info(msg, info):
        infos.append(info)

    node.create_subscription(Int32, 'numbers', lambda msg: received.append(msg.data), 200)
    node.create_subscription(Int32, 'numbers', with_info, 200)
    publisher = node.create_publisher(Int32, 'numbers', 200)
    assert _spin_until(executor, lambda: publisher.get_subscription_count() == 2)
    for i in range(200):
        publisher.publish(Int32(data=i))
    assert _spin_until(executor, lambda: len(received) == 200 and len(infos) == 200)
    assert received == list(range(200))
    assert all(info['source_timestamp'] > 0 for info in infos)


def test_services_clients_and_parameters_set_like_ros2_param(context, executor):
    """A SetBool service answers; parameter sets are applied or refused with the reason."""
    server, caller = _node(context, 'server'), _node(context, 'caller')
    for n in (server, caller):
        executor.add_node(n)
    server.create_service(SetBool, 'toggle', lambda request, response: SetBool.Response(
        success=request.data, message=f'got {request.data}'))
    server.declare_parameter('gain', 1.0, ParameterDescriptor(
        floating_point_range=[FloatingPointRange(from_value=0.0, to_value=10.0)]))
    server.add_on_set_parameters_callback(lambda params: SetParametersResult(
        successful=all(p.value != 7.0 for p in params), reason='seven is refused'))

    client = caller.create_client(SetBool, 'toggle')
    assert _spin_until(executor, client.service_is_ready)
    future = client.call_async(SetBool.Request(data=True))
    executor.spin_until_future_complete(future, timeout_sec=10.0)
    assert future.done() and future.result().success and future.result().message == 'got True'

    parameters = AsyncParameterClient(caller, 'server')
    assert _spin_until(executor, parameters.services_are_ready)

    def set_gain(value):
        future = parameters.set_parameters([Parameter('gain', value=value)])
        executor.spin_until_future_complete(future, timeout_sec=10.0)
        [result] = future.result().results
        return result

    def gain():
        future = parameters.get_parameters(['gain'])
        executor.spin_until_future_complete(future, timeout_sec=10.0)
        return future.result().values[0].double_value

    assert set_gain(2.5).successful and gain() == 2.5
    refused = set_gain(20.0)
    assert not refused.successful and 'range' in refused.reason and gain() == 2.5
    refused = set_gain(7.0)
    assert not refused.successful and refused.reason == 'seven is refused' and gain() == 2.5


def test_guard_conditions_tasks_and_async_callbacks(context, executor):
    """A guard triggered from another thread, create_task coroutines and async callbacks run."""
    node = _node(context, 'async_node')
    executor.add_node(node)
    events = []
    guard = node.create_guard_condition(lambda: events.append('guard'))
    server = node.create_service(SetBool, 'async_toggle', None)

    async def respond(request, response):
        response.success = not request.data
        return response

    server.callback = respond
    client = node.create_client(SetBool, 'async_toggle')

    async def call():
        result = await client.call_async(SetBool.Request(data=True))
        events.append(('task', result.success))
        return 'done'

    assert _spin_until(executor, client.service_is_ready)
    task = executor.create_task(call)
    threading.Timer(0.1, guard.trigger).start()
    assert _spin_until(executor, lambda: task.done() and 'guard' in events)
    assert task.result() == 'done' and ('task', False) in events


def test_entities_created_and_destroyed_while_spinning(context, executor):
    """spin() in a thread picks up a new subscription, drops a destroyed one, and stops."""
    node = _node(context, 'dynamic')
    executor.add_node(node)
    spinner = threading.Thread(target=executor.spin)
    spinner.start()
    try:
        received = []
        subscription = node.create_subscription(Int32, 'late', lambda m: received.append(m.data),
                                                10)
        publisher = node.create_publisher(Int32, 'late', 10)
        end = time.monotonic() + 10.0
        while not received and time.monotonic() < end:
            publisher.publish(Int32(data=1))
            time.sleep(0.02)
        assert received, 'a subscription created while spinning got nothing'
        node.destroy_subscription(subscription)
        time.sleep(0.2)
        count = len(received)
        for _ in range(10):
            publisher.publish(Int32(data=2))
        time.sleep(0.3)
        assert len(received) == count, 'a destroyed subscription still got messages'
    finally:
        executor.shutdown()
        spinner.join(5.0)
    assert not spinner.is_alive()


def test_a_subscription_destroyed_by_a_callback_is_not_called(context, executor):
    """A's callback destroys B (same topic, same wake-up): B never runs, A keeps working."""
    node = _node(context, 'destroyer')
    executor.add_node(node)
    calls = []
    subscriptions = {}

    def first(msg):
        calls.append(('a', msg.data))
        if 'b' in subscriptions:
            node.destroy_subscription(subscriptions.pop('b'))

    node.create_subscription(Int32, 'shared', first, 10)
    subscriptions['b'] = node.create_subscription(
        Int32, 'shared', lambda msg: calls.append(('b', msg.data)), 10)
    publisher = node.create_publisher(Int32, 'shared', 10)
    assert _spin_until(executor, lambda: publisher.get_subscription_count() == 2)
    publisher.publish(Int32(data=1))
    assert _spin_until(executor, lambda: ('a', 1) in calls)
    publisher.publish(Int32(data=2))
    assert _spin_until(executor, lambda: ('a', 2) in calls)
    assert calls == [('a', 1), ('a', 2)]


def _spin_in_thread(executor):
    """Start ``executor.spin()`` in a daemon thread; return it and a list that gets the outcome."""
    outcome = []

    def spin():
        try:
            executor.spin()
        except ExternalShutdownException:
            outcome.append('external shutdown')

    spinner = threading.Thread(target=spin, daemon=True)
    spinner.start()
    return spinner, outcome


def test_context_shutdown_ends_spin(context, executor):
    """Shutting the context down from another thread ends spin() with ExternalShutdownException."""
    executor.add_node(_node(context, 'doomed'))
    spinner, outcome = _spin_in_thread(executor)
    time.sleep(0.2)
    rclpy.try_shutdown(context=context)
    spinner.join(5.0)
    assert not spinner.is_alive() and outcome == ['external shutdown']


def test_a_context_shut_down_under_a_backlog_stops_at_the_next_callback(context, executor):
    """A context shut down in a callback: no queued message is served after it.

    Shut down as rclpy's SIGINT handler does it (rcl only, no executor wake-up);
    spin ends with ExternalShutdownException.
    """
    node = _node(context, 'backlog')
    calls = []

    def on_message(msg):
        calls.append(msg.data)
        if context.ok():
            context.handle.shutdown()

    node.create_subscription(Int32, 'backlog', on_message, RELIABLE)
    publisher = node.create_publisher(Int32, 'backlog', RELIABLE)
    executor.add_node(node)
    for i in range(20):
        publisher.publish(Int32(data=i))
    time.sleep(0.2)
    spinner, outcome = _spin_in_thread(executor)
    spinner.join(5.0)
    assert not spinner.is_alive(), 'spin ignores the shut-down context'
    assert outcome == ['external shutdown'] and calls == [0]


def test_qos_events_reach_their_callbacks(context, executor):
    """An incompatible publisher (best effort vs reliable) raises the subscription's QoS event."""
    node = _node(context, 'qos')
    executor.add_node(node)
    events = []
    node.create_subscription(
        Int32, 'qos_topic', lambda m: None, RELIABLE,
        event_callbacks=SubscriptionEventCallbacks(incompatible_qos=events.append))
    node.create_publisher(Int32, 'qos_topic', QoSProfile(
        depth=1, reliability=ReliabilityPolicy.BEST_EFFORT))
    assert _spin_until(executor, lambda: events, timeout=10.0 + WAITABLE_PERIOD)
    assert events[0].total_count >= 1


def test_node_main_exit_status_bad_configuration_and_ctrl_c():
    """A bad parameter exits 1 with the reason; Ctrl-C on a running node exits 0 cleanly."""
    bad = subprocess.run(
        [sys.executable, '-m', 'polyc2bf_ros.safety_filter_node', '--ros-args',
         '-p', 'model:=hovercraft'], cwd=REPO, capture_output=True, text=True, timeout=60)
    assert bad.returncode == 1, bad.stdout + bad.stderr
    assert 'invalid configuration' in bad.stderr + bad.stdout and 'hovercraft' in bad.stderr

    with running_filter(params={'model': 'unicycle'}) as proc, Harness() as h:
        h.filter_io(proc)
        proc.send_signal(signal.SIGINT)
        assert proc.wait(30.0) == 0, node_log(proc)  # a hang detector: exit takes < 1 s
    assert 'Traceback' not in node_log(proc)
