"""Liveness around the filter: deadlock detection and its resolution.

``deadlock`` detects it; ``circulation`` and ``escape_route`` (a grid route) resolve it.

Imports ``kernels``, ``barrier`` and ``safety_filter``; only ``decision`` imports it.
"""
