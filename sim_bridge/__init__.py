"""PyBullet simulation bridge, nominal controllers, MCAP recording and replay, evaluation.

The test bench around the filter: it imports ``polyc2bf_ros`` (core and shell) as a user
would; nothing in ``polyc2bf_ros`` imports it.
"""
