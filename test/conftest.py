"""Test-wide setup: reproducible hypothesis runs, and a DDS domain per pytest process.

Hypothesis profiles (``settings.load_profile`` runs here, before any test module
builds its ``settings``, so every test inherits the loaded profile's values):

* ``fixed`` (the default, and always when ``CI`` is set): ``derandomize=True``
  (the examples follow from each test's source), a fixed ``max_examples``, no
  deadline, no example database, the ``@reproduce_failure`` blob printed.  The
  same examples on every clone and every run: ``make test`` passes or fails on
  the code, not on chance.  ``too_slow`` is suppressed, since it measures time.
* ``explore``: ``HYPOTHESIS_PROFILE=explore`` or ``make test-explore``: random,
  ``EXPLORE_FACTOR`` times the examples, failures saved in ``.hypothesis/``
  (replayed first next time); ``--hypothesis-seed=N`` repeats a run.  Pin every
  counterexample it finds with ``@example`` beside a fix.
  A test's own ``settings(max_examples=...)`` wins over any profile; tests under
  test/core write ``examples(n)`` (test/core/strategies.py), which is n in
  ``fixed`` and ``EXPLORE_FACTOR * n`` in ``explore``.

The controller process picks a random base domain once and exports it; each
pytest-xdist worker ``gwN`` then uses ``base + N``.  Both variables are set in
``os.environ`` before any test imports rclpy, so rclpy contexts and every child
process a test starts (nodes launched with ``--ros-args``) inherit them.
Set ``POLYC2BF_TEST_DOMAIN_BASE`` to pin the base by hand.

SIGINT is delivered to the programs the tests start even when the suite itself
was started with SIGINT ignored (``make test &`` in a script: a background job
ignores SIGINT, and an ignored signal stays ignored across fork and exec), so
the Ctrl-C tests test the programs, not how the suite was launched.
"""
import os
import random
import signal

from hypothesis import HealthCheck, settings

FIXED_EXAMPLES = 100
EXPLORE_FACTOR = 10
settings.register_profile(
    'fixed', derandomize=True, max_examples=FIXED_EXAMPLES, deadline=None, database=None,
    print_blob=True, suppress_health_check=[HealthCheck.too_slow])
settings.register_profile(
    'explore', derandomize=False, max_examples=EXPLORE_FACTOR * FIXED_EXAMPLES, deadline=None,
    print_blob=True, suppress_health_check=[HealthCheck.too_slow])
_profile = 'fixed' if os.environ.get('CI') else os.environ.get('HYPOTHESIS_PROFILE', 'fixed')
if _profile not in ('fixed', 'explore'):
    raise ValueError(f"HYPOTHESIS_PROFILE must be 'fixed' or 'explore', got {_profile!r}")
settings.load_profile(_profile)

MAX_WORKERS = 16
_base = os.environ.setdefault(
    'POLYC2BF_TEST_DOMAIN_BASE', str(random.randint(1, 100 - MAX_WORKERS)))
_worker = os.environ.get('PYTEST_XDIST_WORKER', 'gw0')
os.environ['ROS_DOMAIN_ID'] = str(int(_base) + int(_worker.removeprefix('gw')))
os.environ['ROS_AUTOMATIC_DISCOVERY_RANGE'] = 'LOCALHOST'
os.environ.pop('ROS_STATIC_PEERS', None)

if signal.getsignal(signal.SIGINT) == signal.SIG_IGN:
    # A caught signal is reset to its default in an exec'd child; an ignored one is not.
    signal.signal(signal.SIGINT, signal.default_int_handler)
