"""Kernels of ``obstacles.scan_conversion``, whose docstring has the math (step 4).

The math in compiled form; every kernel lives in ``core/kernels`` (``jit.kernel_sources``).
"""
from polyc2bf_ros.core.kernels.jit import F1, I1, kernel, signature


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
