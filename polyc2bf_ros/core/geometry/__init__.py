"""Planar geometry of polygons, one at a time and whole obstacle sets at once.

``polygons``: cleaning, hulls, silhouettes, distances; ``views``: the plane each cone
is built in; ``polygon_limits``: bounded outline sizes; ``footprint``: the robot's own
polygon, read from Nav2's format.  Whole sets in one kernel call
are ``kernels.geometry_batch``.

Imports only ``kernels``.
"""
