"""Planar geometry of polygons, one at a time and whole obstacle sets at once.

``polygons``: cleaning, hulls, silhouettes, distances; ``batch``: whole sets in one
kernel call; ``views``: the plane each cone is built in; ``polygon_limits``: bounded
outline sizes.

Imports only ``kernels``.
"""
