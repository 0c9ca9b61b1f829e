"""A single-threaded executor with rclpy's API and a fraction of its per-callback cost.

rclpy's ``SingleThreadedExecutor`` rebuilds its whole wait list, a new rcl wait
set, a generator and a ``Task`` per callback on every ``spin_once``.  At a
kHz control rate that bookkeeping costs more than the safety filter itself
(doc/safety_filter.md, "Executor").  ``LeanExecutor`` keeps the
``rclpy.executors.Executor`` API (``add_node``, ``spin``, ``spin_once``,
``spin_until_future_complete``, ``create_task``, ``shutdown``), so a node
switches by changing one line, and does the minimum per wake-up:

- **Plan.** The entities of every added node (subscriptions, timers,
  services, clients, guard conditions, waitables such as QoS events) are
  gathered once into plain lists with one preallocated rcl wait set.  rclpy
  calls ``Executor.wake()`` whenever a node creates or destroys an entity and
  ``add_node`` / ``remove_node`` trigger the executor's guard condition; both
  mark the plan for a rebuild before the next wait.  While a plan is in use it
  holds each handle "in use", so an entity destroyed meanwhile (by a callback
  or another thread) is freed only after the rebuild, never under a wait.
- **Wait.** Refill the wait set from the cached handles (rcl clears the
  entries that were not ready) and wait.
- **Dispatch**, in this order, calling callbacks directly: guard conditions;
  subscriptions in creation order, taking every queued message (at most the
  queue depth, so a flood cannot starve the rest); ready timers; service
  requests (answered at once); client responses (the future completes);
  waitables (QoS events: rare, so they join the wait only every
  ``WAITABLE_PERIOD`` = 0.1 s); then tasks from ``create_task`` and ``async``
  callbacks, which run as ``rclpy.task.Task`` and are resumed on later spins
  until done.  If the entities change during dispatch, it stops; what is left
  stays ready in rcl and is served after the rebuild, so a destroyed entity is
  never called.
- **Shutdown.** The context is checked after every wait and before every
  callback (``handle.ok()``, ~0.2 us): rclpy's SIGINT handler shuts the
  context down at once, and a shut-down context ends the spin with
  ``ExternalShutdownException`` at the next callback boundary, however much is
  queued.  So Ctrl-C acts within one callback even when the Python
  ``KeyboardInterrupt`` never comes (SIGINT ignored at start, as for a
  background job of a script) or the guard condition's wake-up came before the
  context was down, and no callback runs with a dead context (its publish
  would raise).

Differences from ``SingleThreadedExecutor``: ``spin_once`` runs *every*
callback that is ready after one wait (not just one), and with waitables
present it waits at most ``WAITABLE_PERIOD``; callback groups are not
consulted (one thread runs everything, so every group is trivially mutually
exclusive).  Exceptions from callbacks propagate out of ``spin`` /
``spin_once``; a shut-down context ends ``spin`` with
``ExternalShutdownException`` and Ctrl-C with ``KeyboardInterrupt``, as with
rclpy's executors.

Private rclpy API (rclpy 7.1, ROS 2 Jazzy), through ``rclpy_private`` and
checked by test/node/test_rclpy_private.py:

- ``rclpy.impl.implementation_singleton.rclpy_implementation.WaitSet`` (the rcl
  wait set) and the entity handles' ``take_message``, ``call_timer``,
  ``is_timer_ready``, ``service_take_request``, ``take_response`` and
  ``pointer``, exactly as ``rclpy.executors`` and ``rclpy.wait_for_message``
  use them;
- ``Executor._guard`` (triggered by ``add_node`` / ``remove_node`` /
  ``wake``), ``Executor._sigint_gc`` (triggered by Ctrl-C) and
  ``Executor._is_shutdown``;
- ``Subscription._callback_type`` (whether the callback also takes the
  ``MessageInfo``).
"""
import collections
import contextlib
import inspect
import threading
import time

from rclpy.exceptions import InvalidHandle
from rclpy.executors import Executor, ExternalShutdownException, TimeoutObject
from rclpy.subscription import Subscription
from rclpy.task import Task
from rclpy.utilities import timeout_sec_to_nsec
from rclpy.waitable import NumberOfEntities

from polyc2bf_ros import rclpy_private

_WITH_INFO = Subscription.CallbackType.WithMessageInfo
# Waitables (in practice the QoS event handlers rclpy attaches to every publisher and
# subscription: "incompatible QoS" warnings) are rare and level-triggered; polling them
# at this period [s] instead of on every wake-up saves a Python call per handler per wake.
WAITABLE_PERIOD = 0.1


def _ready(wait_set, kind, entries):
    """Return the ``(handle, pointer, ...)`` entries of ``kind`` the last wait found ready."""
    if not entries:
        return ()
    ready = wait_set.get_ready_entities(kind)
    return [entry for entry in entries if entry[1] in ready] if ready else ()


class _Plan:
    """Handles of every entity of ``nodes`` plus the executor's guards, held in use."""

    def __init__(self, nodes, guards, context, wrap):
        """Gather entities, mark their handles in use, size one wait set for them.

        ``wrap(callback)`` returns what to call: the callback itself, or for a
        coroutine function a function that starts it as a task.
        """
        self._held = contextlib.ExitStack()
        hold = self._hold
        hold(context.handle)
        self.context_ok = context.handle.ok
        self.subscriptions = [
            (s.handle, s.handle.pointer, s.msg_type, s.raw, wrap(s.callback),
             s._callback_type == _WITH_INFO, max(1, s.qos_profile.depth))
            for n in nodes for s in n.subscriptions if hold(s.handle)]
        self.timers = [(t.handle, t.handle.pointer, wrap(t.callback))
                       for n in nodes for t in n.timers if hold(t.handle)]
        self.services = [(s.handle, s.handle.pointer, s)
                         for n in nodes for s in n.services if hold(s.handle)]
        self.clients = [(c.handle, c.handle.pointer, c)
                        for n in nodes for c in n.clients if hold(c.handle)]
        self.guards = [(g.handle, g.handle.pointer, wrap(g.callback))
                       for g in [*guards, *(g for n in nodes for g in n.guards)]
                       if hold(g.handle)]
        self.waitables = [w for n in nodes for w in n.waitables if hold(w)]
        self._waitables_due = 0.0
        count = NumberOfEntities(len(self.subscriptions), len(self.guards), len(self.timers),
                                 len(self.clients), len(self.services))
        for waitable in self.waitables:
            count += waitable.get_num_entities()
        self.wait_set = wait_set = rclpy_private.WaitSet(
            count.num_subscriptions, count.num_guard_conditions, count.num_timers,
            count.num_clients, count.num_services, count.num_events, context.handle)
        # (bound add method, handle) of every entity but the waitables, in refill order.
        self._entries = tuple(
            [(wait_set.add_subscription, entry[0]) for entry in self.subscriptions]
            + [(wait_set.add_timer, entry[0]) for entry in self.timers]
            + [(wait_set.add_service, entry[0]) for entry in self.services]
            + [(wait_set.add_client, entry[0]) for entry in self.clients]
            + [(wait_set.add_guard_condition, entry[0]) for entry in self.guards])

    def _hold(self, entity):
        """Mark ``entity`` in use until ``release``; False if it is already destroyed."""
        try:
            self._held.enter_context(entity)
        except InvalidHandle:
            return False
        return True

    def release(self):
        """Let the entities be destroyed again; free the wait set."""
        self._entries = ()
        self.wait_set.destroy_when_not_in_use()
        self._held.close()

    def wait(self, timeout_nsec):
        """Refill the wait set and block until something is ready or the timeout passes.

        Waitables join every ``WAITABLE_PERIOD`` s only (the wait is cut short
        for them); return whether they were in this wait.
        """
        wait_set = self.wait_set
        wait_set.clear_entities()
        for add, handle in self._entries:
            add(handle)
        with_waitables = False
        if self.waitables:
            now = time.monotonic()
            with_waitables = now >= self._waitables_due
            if with_waitables:
                for waitable in self.waitables:
                    waitable.add_to_wait_set(wait_set)
                self._waitables_due = now + WAITABLE_PERIOD
            else:
                cap = int(1e9 * (self._waitables_due - now)) + 1
                timeout_nsec = cap if timeout_nsec < 0 else min(timeout_nsec, cap)
        wait_set.wait(timeout_nsec)
        return with_waitables


class LeanExecutor(Executor):
    """Single-threaded executor with a cached wait plan (see the module docstring)."""

    def __init__(self, *, context=None):
        """Create the executor for ``context`` (default: the global context)."""
        super().__init__(context=context)
        self._plan = None
        self._stale = True
        self._pending = collections.deque()
        self._pending_lock = threading.Lock()

    # -- Executor API ------------------------------------------------------------------------

    def add_node(self, node):
        """Add ``node``; its entities join the plan before the next wait."""
        self._stale = True
        return super().add_node(node)

    def remove_node(self, node):
        """Remove ``node``; its entities leave the plan before the next wait."""
        self._stale = True
        super().remove_node(node)

    def wake(self):
        """Rebuild the plan before the next wait (an entity was created or destroyed)."""
        self._stale = True
        super().wake()

    def create_task(self, callback, *args, **kwargs):
        """Run ``callback(*args, **kwargs)`` (a function or coroutine) in the spinning thread."""
        task = Task(callback, args, kwargs, executor=self)
        with self._pending_lock:
            self._pending.append(task)
        guard = self._guard
        if guard is not None:
            guard.trigger()
        return task

    def spin(self):
        """Execute callbacks until the context or the executor is shut down."""
        if not self._context.ok():
            raise ExternalShutdownException()
        try:
            while not self._is_shutdown:
                self._spin(None)
        finally:
            self._release()

    def spin_once(self, timeout_sec=None):
        """Wait once (at most ``timeout_sec`` s; ``None`` = forever) and run what is ready."""
        try:
            self._spin(timeout_sec)
        finally:
            self._release()

    def spin_once_until_future_complete(self, future, timeout_sec=None):
        """``spin_once`` for ``spin_until_future_complete`` (which wakes us when it is done)."""
        if isinstance(timeout_sec, TimeoutObject):
            timeout_sec = timeout_sec.timeout
        if not future.done():
            self.spin_once(timeout_sec)

    # -- one wake-up -------------------------------------------------------------------------

    def _release(self):
        if self._plan is not None:
            self._plan.release()
            self._plan = None

    def _spin(self, timeout_sec):
        """Run pending tasks, wait once, dispatch everything ready (module docstring order)."""
        if self._pending:
            self._run_tasks()
        if self._stale or self._plan is None:
            self._release()
            self._stale = False
            if self._is_shutdown:
                return
            self._plan = _Plan(self.get_nodes(), (self._guard, self._sigint_gc), self._context,
                               self._wrap)
        plan = self._plan
        with_waitables = plan.wait(timeout_sec_to_nsec(timeout_sec))
        if self._is_shutdown:
            return
        self._dispatch(plan, with_waitables)
        if not plan.context_ok():  # before, during or after dispatch: Ctrl-C or shutdown
            raise ExternalShutdownException()
        if self._pending:
            self._run_tasks()

    def _dispatch(self, plan, with_waitables):
        """Call what the last wait found ready, guard conditions first (the wait took them).

        Everything else stays ready in rcl until taken (queued messages, due
        timers, requests, responses, QoS events).  So when the entities change
        meanwhile (``wake``) or the context is shut down, dispatch stops before
        the next callback; the rest is served after the rebuild (a destroyed
        entity is never called), or never.
        """
        wait_set = plan.wait_set
        ok = plan.context_ok
        if not ok():
            return
        guards_ready = wait_set.get_ready_entities('guard_condition')
        for _, pointer, callback in plan.guards:
            if pointer in guards_ready and callback is not None:
                callback()
        for handle, _, msg_type, raw, callback, with_info, depth in _ready(
                wait_set, 'subscription', plan.subscriptions):
            for _ in range(depth):
                if self._stale or not ok():
                    return
                taken = handle.take_message(msg_type, raw)
                if taken is None:
                    break
                if with_info:
                    callback(*taken)
                else:
                    callback(taken[0])
        for handle, _, callback in _ready(wait_set, 'timer', plan.timers):
            if self._stale or not ok():
                return
            if handle.is_timer_ready():
                handle.call_timer()
                callback()
        for handle, _, service in _ready(wait_set, 'service', plan.services):
            if self._stale or not ok():
                return
            self._serve(handle, service)
        for handle, _, client in _ready(wait_set, 'client', plan.clients):
            if self._stale or not ok():
                return
            self._complete(handle, client)
        if with_waitables:
            for waitable in plan.waitables:
                if self._stale or not ok():
                    return
                if waitable.is_ready(wait_set):
                    self._start(waitable.execute, waitable.take_data())

    def _wrap(self, callback):
        """Return ``callback``, or for a coroutine function a function starting it as a task."""
        if not inspect.iscoroutinefunction(callback):
            return callback
        return lambda *args: self._start(callback, *args)

    def _serve(self, handle, service):
        """Take one request and send the callback's response (``async`` callbacks too)."""
        request, header = handle.service_take_request(service.srv_type.Request)
        if header is None:
            return
        callback = service.callback
        if not inspect.iscoroutinefunction(callback):
            service.send_response(callback(request, service.srv_type.Response()), header)
            return

        async def respond():
            service.send_response(await callback(request, service.srv_type.Response()), header)
        self._start(respond)

    def _complete(self, handle, client):
        """Take one response and complete the future of its request (if still pending)."""
        header, response = handle.take_response(client.srv_type.Response)
        if header is None:
            return
        try:
            future = client.get_pending_request(header.request_id.sequence_number)
        except KeyError:  # cancelled meanwhile
            return
        future.set_result(response)

    def _start(self, callback, *args):
        """Run ``callback(*args)`` as a task now; keep it if it awaits something."""
        task = Task(callback, args, None, executor=self)
        task()
        if not task.done():
            with self._pending_lock:
                self._pending.append(task)
        elif task.exception() is not None:
            raise task.exception()

    def _run_tasks(self):
        """Resume every pending task once; raise the first exception of a finished one."""
        with self._pending_lock:
            tasks = list(self._pending)
            self._pending.clear()
        for index, task in enumerate(tasks):
            task()
            if not task.done():
                with self._pending_lock:
                    self._pending.append(task)
            elif task.exception() is not None:
                with self._pending_lock:
                    self._pending.extend(t for t in tasks[index + 1:] if not t.done())
                raise task.exception()
