"""Bounded polygon sizes: what the filter does with outlines too large to use as they are.

Every obstacle costs the filter per vertex (cleaning is O(n^2), convex decomposition by ear
clipping O(n^3) in the worst case) and per convex part (one QP row each), so inputs are capped
before that work starts.  Each reduction is conservative: the result *contains* the input, so
a barrier that keeps the robot out of the result keeps it out of the input.

* **Vertex cap.**  More than ``max_vertices`` outline points are replaced by the convex hull;
  a hull that still has more vertices is replaced by its circumscribed ``max_vertices``-gon
  with evenly spaced edge normals ``n_i = (cos(2 pi i / K), sin(2 pi i / K))`` and support
  values ``s_i = max_p <n_i, p>``::

      P_K = { x : <n_i, x> <= s_i  for i = 0..K-1 }  contains the hull,

  whose vertices are the intersections of consecutive support lines.  It lies within
  ``R (1 / cos(pi / K) - 1)`` of the hull (R: the hull's circumradius about any point in it).
* **Convex-parts cap.**  A simple polygon with r reflex vertices needs at least
  ``ceil(r / 2) + 1`` convex parts (each cut removes at most two reflex vertices), so a
  polygon above ``max_parts`` by that bound is never decomposed; it, or one whose
  decomposition exceeds the cap, is replaced by its convex hull.
"""
import math

import numpy as np

from polyc2bf_ros.core.geometry.polygons import clean_polygon, convex_hull, decompose_convex

# Defaults: outline points per polygon, convex parts per non-convex footprint.
MAX_VERTICES = 256
MAX_PARTS = 64

# A support line closer than this (relative to the polygon's size) to its neighbour's
# intersection point adds no vertex.
_MERGE_TOLERANCE = 1e-9


def enclosing_polygon(points, max_vertices):
    """Return a convex CCW polygon with at most ``max_vertices`` vertices containing ``points``.

    ``points`` (n, 2) finite; the convex hull when it is small enough, else the
    circumscribed polygon of the module docstring.  Raises ``ValueError`` for fewer than
    3 points that are not all on one line, and for ``max_vertices`` < 3.
    """
    if max_vertices < 3:
        raise ValueError(f'max_vertices must be >= 3, got {max_vertices}')
    hull = convex_hull(points)
    if len(hull) < 3:
        raise ValueError('the points span no area (a point or a segment)')
    if len(hull) <= max_vertices:
        return hull
    angles = 2.0 * math.pi * np.arange(max_vertices) / max_vertices
    normals = np.column_stack([np.cos(angles), np.sin(angles)])
    support = (hull @ normals.T).max(axis=0)
    # Vertex i: n_i . x = s_i and n_{i+1} . x = s_{i+1} (Cramer's rule; det = sin(2 pi / K)).
    n2, s2 = np.roll(normals, -1, axis=0), np.roll(support, -1)
    det = normals[:, 0] * n2[:, 1] - normals[:, 1] * n2[:, 0]
    x = (support * n2[:, 1] - s2 * normals[:, 1]) / det
    y = (normals[:, 0] * s2 - n2[:, 0] * support) / det
    vertices = np.column_stack([x, y])
    size = float(np.ptp(hull, axis=0).max())
    step = np.linalg.norm(vertices - np.roll(vertices, 1, axis=0), axis=1)
    vertices = vertices[step > _MERGE_TOLERANCE * size]
    return clean_polygon(vertices)


def reflex_count(polygon):
    """Return the number of reflex (right-turning) vertices of a CCW polygon."""
    pts = np.asarray(polygon, dtype=np.float64)
    incoming = pts - np.roll(pts, 1, axis=0)
    outgoing = np.roll(incoming, -1, axis=0)
    turn = incoming[:, 0] * outgoing[:, 1] - incoming[:, 1] * outgoing[:, 0]
    return int(np.count_nonzero(turn < 0.0))


def bounded_convex_parts(polygon, max_parts):
    """Return ``(convex parts, capped)`` of a clean CCW polygon, at most ``max_parts`` of them.

    ``capped`` is True when the polygon was replaced by its convex hull (module docstring).
    """
    if math.ceil(reflex_count(polygon) / 2) + 1 <= max_parts:
        parts = decompose_convex(polygon)
        if len(parts) <= max_parts:
            return parts, False
    return [convex_hull(polygon)], True
