"""Kernels of ``liveness.escape_route``, whose docstring has the math.

The math in compiled form; every kernel lives in ``core/kernels`` (``jit.kernel_sources``).
"""
import math

from polyc2bf_ros.core.kernels.cones import nearest_edge, polygon_box
from polyc2bf_ros.core.kernels.jit import F1, F2, I1, kernel, signature

START_CELLS = 3
_DIAGONAL = math.sqrt(2.0)


@kernel(signature('void', F2, F2, F2, F2, F2, I1, 'f8', 'f8', 'f8', 'f8', F2))
def grid_clearance(x, y, edge_x, edge_y, inv_sq, counts, x0, y0, cell, cutoff, out):
    """Fill ``out`` (rows i, columns j) with min(cutoff, signed distance of cell centres).

    Cell (i, j) has its centre at (x0 + j cell, y0 + i cell); polygon n (rows of ``x``,
    ``y``, as ``cones.PlanarPolygons``) is only measured at cells within ``cutoff`` of its
    bounding box.  Negative inside.
    """
    rows, columns = out.shape
    for i in range(rows):
        for j in range(columns):
            out[i, j] = cutoff
    for n in range(counts.shape[0]):
        low_x, high_x, low_y, high_y = polygon_box(x, y, counts[n], n)
        first_i = max(0, int(math.floor((low_y - cutoff - y0) / cell)))
        last_i = min(rows - 1, int(math.ceil((high_y + cutoff - y0) / cell)))
        first_j = max(0, int(math.floor((low_x - cutoff - x0) / cell)))
        last_j = min(columns - 1, int(math.ceil((high_x + cutoff - x0) / cell)))
        for i in range(first_i, last_i + 1):
            for j in range(first_j, last_j + 1):
                square, _, _, _, inside = nearest_edge(
                    x, y, edge_x, edge_y, inv_sq, counts[n], n, x0 + j * cell, y0 + i * cell)
                distance = -math.sqrt(square) if inside else math.sqrt(square)
                out[i, j] = min(out[i, j], distance)



@kernel
def _push(heap_cost, heap_index, size, cost, index):
    """Push (cost, index) onto the binary min-heap held in the first ``size`` slots."""
    k = size
    heap_cost[k], heap_index[k] = cost, index
    while k > 0:
        parent = (k - 1) // 2
        if heap_cost[parent] <= heap_cost[k]:
            break
        heap_cost[parent], heap_cost[k] = heap_cost[k], heap_cost[parent]
        heap_index[parent], heap_index[k] = heap_index[k], heap_index[parent]
        k = parent
    return size + 1



@kernel
def _pop(heap_cost, heap_index, size):
    """Remove the heap's smallest entry; return (cost, index, new size)."""
    cost, index = heap_cost[0], heap_index[0]
    size -= 1
    heap_cost[0], heap_index[0] = heap_cost[size], heap_index[size]
    k = 0
    while True:
        child = 2 * k + 1
        if child >= size:
            break
        if child + 1 < size and heap_cost[child + 1] < heap_cost[child]:
            child += 1
        if heap_cost[k] <= heap_cost[child]:
            break
        heap_cost[child], heap_cost[k] = heap_cost[k], heap_cost[child]
        heap_index[child], heap_index[k] = heap_index[k], heap_index[child]
        k = child
    return cost, index, size



@kernel(signature('i8', F2, F2, F2, 'i8', 'i8', 'f8', 'f8', 'f8', 'f8', 'f8', 'f8', 'f8',
                  'f8', I1, F1, I1))
def route_search(clearance, unseen, run_clear, start_i, start_j, dir_x, dir_y, ahead, free,
                 start_free, preferred, weight, unseen_weight, parent, cost, heap_index):
    """Return the flat index of the route's end cell, or -1; ``parent`` holds the route.

    Dijkstra from (start_i, start_j) over 8-connected cells with clearance >= ``free``
    (>= ``start_free`` within ``START_CELLS`` of the start), step cost = length in cells
    times 1 + weight max(0, preferred - c) / (preferred - free), and times 1 +
    ``unseen_weight`` into a cell whose ``unseen`` is 1 (0: seen).  The end is the first
    cell popped whose offset from the start, in cells, along (dir_x, dir_y) is >= ``ahead``
    with clearance >= (free + preferred) / 2 and ``run_clear`` 1 (a clear run on past it);
    when no such cell is reached, the first popped that meets all but ``run_clear``.
    Scratch: ``cost`` (9 rows x columns: the cells' costs, then the heap's keys) and
    ``heap_index`` (8 rows x columns: each cell enters the heap at most once per neighbour).
    """
    rows, columns = clearance.shape
    cells = rows * columns
    for k in range(cells):
        cost[k] = math.inf
        parent[k] = -1
    heap_cost = cost[cells:]
    start = start_i * columns + start_j
    cost[start] = 0.0
    size = _push(heap_cost, heap_index, 0, 0.0, start)
    span = preferred - free
    goal_clearance = 0.5 * (free + preferred)
    fallback = -1
    while size > 0:
        here, index, size = _pop(heap_cost, heap_index, size)
        if here > cost[index]:
            continue
        i, j = index // columns, index % columns
        if ((i - start_i) * dir_y + (j - start_j) * dir_x >= ahead
                and clearance[i, j] >= goal_clearance):
            if run_clear[i, j] > 0.0:
                return index
            if fallback < 0:
                fallback = index
        for di in range(-1, 2):
            for dj in range(-1, 2):
                ni, nj = i + di, j + dj
                if (di == 0 and dj == 0) or ni < 0 or nj < 0 or ni >= rows or nj >= columns:
                    continue
                c = clearance[ni, nj]
                near = max(abs(ni - start_i), abs(nj - start_j)) <= START_CELLS
                if c < free and not (near and c >= start_free):
                    continue
                step = _DIAGONAL if di != 0 and dj != 0 else 1.0
                step *= 1.0 + weight * max(0.0, preferred - c) / span
                step *= 1.0 + unseen_weight * unseen[ni, nj]
                neighbour = ni * columns + nj
                if here + step < cost[neighbour] and size < heap_index.shape[0]:
                    cost[neighbour] = here + step
                    parent[neighbour] = index
                    size = _push(heap_cost, heap_index, size, here + step, neighbour)
    return fallback
