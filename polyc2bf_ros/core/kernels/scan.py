"""Kernels of ``obstacles.scan_conversion``, whose docstring has the math (step 4).

The math in compiled form; every kernel lives in ``core/kernels`` (``jit.kernel_sources``).
"""
import math

from polyc2bf_ros.core.kernels.jit import B1, F1, F3, I1, kernel, signature

MIN_APEX_DEPTH = 1.0e-4
"""How far [m] a piece's deepest point must lie in front of its chord to become a corner."""


@kernel
def _worst_point(px, py, first, last):
    """Return (index, squared distance) of the point farthest from the chord first-last.

    Among points ``first + 1 .. last - 1``, the first of equals; (-1, -1) when there is none.

    The distance as ``geometry.polygons._segment_square_distances`` computes it, term by
    term: |r - t e|^2, t = clip(<r, e> / |e|^2, 0, 1), 1 / |e|^2 taken as 0 for |e| = 0.
    """
    ax, ay = px[first], py[first]
    ex, ey = px[last] - ax, py[last] - ay
    square = ex * ex + ey * ey
    inv_sq = 1.0 / square if square > 0.0 else 0.0
    worst, worst_square = -1, -1.0
    for i in range(first + 1, last):
        rx, ry = px[i] - ax, py[i] - ay
        t = min(max((rx * ex + ry * ey) * inv_sq, 0.0), 1.0)
        dx, dy = rx - t * ex, ry - t * ey
        deviation = dx * dx + dy * dy
        if deviation > worst_square:
            worst, worst_square = i, deviation
    return worst, worst_square


@kernel(signature('i8', F1, F1, I1, 'f8', I1, I1))
def split_to_tolerance(px, py, ends, tolerance_sq, out, stack):
    """Write the sorted piece ends into ``out``; return how many (step 4, split).

    Every piece between consecutive ``ends`` (sorted point indices) is split at its point
    farthest from its chord (the first of equals) while that squared distance exceeds
    ``tolerance_sq``, depth first, left piece first, so that the ends come out sorted: the
    same ends as splitting every piece one level at a time.  ``out`` and ``stack`` (scratch)
    hold at least ``len(px) + 1`` and ``2 len(px) + 2`` entries.
    """
    count = 0
    for j in range(ends.shape[0] - 1):
        stack[0], stack[1] = ends[j], ends[j + 1]
        depth = 1
        while depth:
            depth -= 1
            first, last = stack[2 * depth], stack[2 * depth + 1]
            worst, worst_square = _worst_point(px, py, first, last)
            if worst >= 0 and worst_square > tolerance_sq:
                stack[2 * depth], stack[2 * depth + 1] = worst, last
                stack[2 * depth + 2], stack[2 * depth + 3] = first, worst
                depth += 2
            else:
                out[count] = first
                count += 1
    if ends.shape[0]:
        out[count] = ends[ends.shape[0] - 1]
        count += 1
    return count


@kernel(signature('void', F3, F1, F1, I1, I1, 'f8', 'f8', 'f8', F3, B1))
def front(polygons, px, py, first, last, base_x, base_y, radius, corners, pointed):
    """Bring each piece's near side to its points (step 6); fill ``corners`` and ``pointed``.

    Piece k is points ``first[k] .. last[k]`` and rectangle ``polygons[k]`` (near edge
    corners 0, 1).  ``corners`` (M, 5, 2): corner 0, the apex point, corners 1-3, the near
    ones (0-2) moved back by the shift; ``pointed[k]``: the apex is a corner (else corners
    0, 2, 3, 4 are the polygon).  ``radius``: the footprint radius.  Term by term as the
    numpy steps it replaced (``scan_conversion._front``'s docstring has the math), so the
    polygons are the same to the bit.
    """
    for k in range(polygons.shape[0]):
        ax, ay = polygons[k, 0, 0], polygons[k, 0, 1]
        ex, ey = polygons[k, 1, 0] - ax, polygons[k, 1, 1] - ay
        length = math.sqrt(ex * ex + ey * ey)
        ex, ey = ex / length, ey / length
        nx, ny = -ey, ex
        depth, apex, apex_along = -math.inf, first[k], 0.0
        for i in range(first[k], last[k] + 1):
            rel_x, rel_y = px[i] - ax, py[i] - ay
            ahead = -(rel_x * nx + rel_y * ny)
            if ahead > depth:
                depth, apex, apex_along = ahead, i, rel_x * ex + rel_y * ey
        height = (ax - base_x) * nx + (ay - base_y) * ny
        room = height - radius if height >= 0.0 else math.inf  # a base behind: moves away
        sharp = (depth > MIN_APEX_DEPTH and apex_along > 0.0 and apex_along < length
                 and room >= depth)
        rise = depth / apex_along if sharp else 0.0
        fall = depth / (length - apex_along) if sharp else 0.0
        residual = -math.inf
        for i in range(first[k], last[k] + 1):
            rel_x, rel_y = px[i] - ax, py[i] - ay
            along = rel_x * ex + rel_y * ey
            ahead = -(rel_x * nx + rel_y * ny)
            chain = max(min(rise * along, fall * (length - along)), 0.0)
            residual = max(residual, ahead - chain)
        residual = max(residual, 0.0)
        lateral = max(max(-(base_x - ax) * ex - (base_y - ay) * ey,
                          (base_x - ax) * ex + (base_y - ay) * ey - length), 0.0)
        clear = radius * radius - lateral * lateral
        edge_room = (height - math.sqrt(max(clear, 0.0)) if clear > 0.0 and height >= 0.0
                     else math.inf)
        shift = min(residual, max(room - depth if sharp else edge_room, 0.0))
        corners[k, 0, 0], corners[k, 0, 1] = ax, ay
        corners[k, 1, 0], corners[k, 1, 1] = px[apex], py[apex]
        for c in range(1, 4):
            corners[k, c + 1, 0], corners[k, c + 1, 1] = polygons[k, c, 0], polygons[k, c, 1]
        for c in range(3):
            corners[k, c, 0] -= shift * nx
            corners[k, c, 1] -= shift * ny
        pointed[k] = sharp
