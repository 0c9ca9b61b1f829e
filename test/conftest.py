"""Test-wide setup: every pytest process gets its own DDS domain on loopback.

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
