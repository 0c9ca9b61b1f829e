"""Obstacles: the set the filter consumes, and where it comes from.

``obstacle_set``: the padded, vectorised set; ``marker_tracker`` and
``constant_velocity``: marker tracks; ``scan_conversion``: laser scans to polygons;
``scan_tracker``: their tracks; ``ground``: the ground for 3-D models.

Imports ``kernels`` and ``geometry``.
"""
