"""Kernels of ``obstacles.scan_tracker`` and ``obstacles.constant_velocity`` (their math).

The math in compiled form; every kernel lives in ``core/kernels`` (``jit.kernel_sources``).
Over 500 lines on purpose: the kernels (registration, gating, assignment, the Kalman step)
share one settings vector and one array layout of the tracks.
"""
import math

import numpy as np

from polyc2bf_ros.core.kernels.jit import B1, F1, F2, F3, I1, kernel, signature

RIDGE = 1.0e-3
"""lambda: the prior information on the displacement, in points (module docstring, step 3)."""
LEAK = 2.0
"""kappa: how many times its expected size the information leaked by noisy normals is removed."""
CORNER = math.cos(math.radians(45.0))
"""A point where the chain turns by more than this angle is a corner and is not paired."""
REST_VARIANCE = 2.0
"""A registration is replaced by one from rest (d = 0, trim ``trim``) that keeps as many pairs
with at most this many times its residual variance (module docstring, step 3)."""
MIN_INFORMATION = 2.0
"""An eigenvalue of H below this many points' worth of information is taken as none."""
STRIDE = 3.0
"""Registration pairs every (mean window size / STRIDE)-th centroid of a dense chain."""
WALK = 2
"""How many outline points either side of the last pair the nearest-point search looks at."""
FAR = 1.0e6
"""The cost of a pair outside the gate [m] (real costs are a few metres at most)."""

# Columns of the per-track arrays: floats (bounding box, centroid, last matched stamp, last
# stamp it was moving) and integers (id, hits, moving streak, moving, outline first, size,
# trusted streak).  A track's filter state
# is [p, v, c] (``constant_velocity``, with the clone c of its position at its outline).
LOW, HIGH, CENTROID, SEEN, MOVED, TRACK_FLOATS = 0, 2, 4, 6, 7, 8
ID, HITS, STREAK, MOVING, FIRST, SIZE, TRUST, TRACK_INTS = range(8)

# Entries of the settings vector the kernels read.
(GATE, ACCEL, SPEED, POINT, TRIM, SPAN, ITERATIONS, OVERLAP, CONFIRM, COAST, MOVING_SPEED,
 SIGMAS, SCANS, KNOWN, EXTENT, LINK, POSE, HEADING, SHARE, TRUSTED, DISTRUST, BESIDE, ORIGIN_X,
 ORIGIN_Y, PARAMETERS) = range(25)
I2 = 'i8[:, ::1]'
B2 = 'b1[:, ::1]'


@kernel
def _smooth(points, first, count, span, out, sums):
    """Fill ``out[:count]`` (7 columns) for the chain ``points[first:first + count]`` (step 3).

    Per point j, its window a..b = j - w..j + w with w the largest whose end points lie at
    most ``span`` apart (found from the previous point's w, and summed from the running sums
    ``sums`` (count + 1, 2): linear in the chain's length).  Row j: the window's centroid
    c_j (2), the unit tangent (2) and length of the chord from point min(a, j - 1) to point
    max(b, j + 1) (clipped to the chain), the window's size m_j, and 1 when the window is
    whole (it stopped at ``span``, not at an end of the chain, and the chain does not turn
    at point j by more than ``CORNER``'s angle between the chord's halves), else 0.
    """
    span_sq = span * span
    sums[0, 0] = sums[0, 1] = 0.0
    for k in range(count):
        sums[k + 1, 0] = sums[k, 0] + points[first + k, 0]
        sums[k + 1, 1] = sums[k, 1] + points[first + k, 1]
    w = 0
    for j in range(count):
        w = max(min(w - 1, j, count - 1 - j), 0)
        while w > 0 and _chord_sq(points, first, j - w, j + w) > span_sq:
            w -= 1
        whole = 0.0
        while True:
            if w >= j or w >= count - 1 - j:
                break
            if _chord_sq(points, first, j - w - 1, j + w + 1) > span_sq:
                whole = 1.0
                break
            w += 1
        a, b = j - w, j + w
        size = b - a + 1
        out[j, 0] = (sums[b + 1, 0] - sums[a, 0]) / size
        out[j, 1] = (sums[b + 1, 1] - sums[a, 1]) / size
        start = min(a, j - 1) if j > 0 else a
        stop = max(b, j + 1) if j < count - 1 else b
        qx, qy = points[first + j, 0], points[first + j, 1]
        bx, by = qx - points[first + start, 0], qy - points[first + start, 1]
        fx, fy = points[first + stop, 0] - qx, points[first + stop, 1] - qy
        if bx * fx + by * fy < CORNER * math.sqrt((bx * bx + by * by) * (fx * fx + fy * fy)):
            whole = 0.0  # the chain turns at point j: a corner, whose line is ambiguous
        tx, ty = bx + fx, by + fy
        length = math.sqrt(tx * tx + ty * ty)
        if length > 0.0:
            out[j, 2], out[j, 3], out[j, 4] = tx / length, ty / length, length
        else:
            out[j, 2], out[j, 3], out[j, 4] = 1.0, 0.0, 0.0
        out[j, 5] = size
        out[j, 6] = whole



@kernel
def _chord_sq(points, first, a, b):
    """Return the squared distance between chain points a and b."""
    ex = points[first + b, 0] - points[first + a, 0]
    ey = points[first + b, 1] - points[first + a, 1]
    return ex * ex + ey * ey



@kernel
def _nearest(outline, count, j, x, y, reach_sq):
    """Return (j, squared distance) of the outline centroid (rows of ``outline``) nearest (x, y).

    From row ``j`` (-1: none yet) the search looks ``WALK`` rows either side and moves to
    the nearest, until that is where it stands; the whole outline is searched at the start
    and when the walk stops farther than ``reach_sq``.
    """
    if j >= 0:
        best = (x - outline[j, 0]) ** 2 + (y - outline[j, 1]) ** 2
        while True:
            at = j
            for k in range(max(at - WALK, 0), min(at + WALK + 1, count)):
                distance = (x - outline[k, 0]) ** 2 + (y - outline[k, 1]) ** 2
                if distance < best:
                    best, j = distance, k
            if j == at:
                break
        if best <= reach_sq:
            return j, best
    else:
        j, best = 0, (x - outline[0, 0]) ** 2 + (y - outline[0, 1]) ** 2
    for k in range(count):
        distance = (x - outline[k, 0]) ** 2 + (y - outline[k, 1]) ** 2
        if distance < best:
            best, j = distance, k
    return j, best



@kernel
def _eigen(a, b, d):
    """Return (m, h, ux, uy) of the symmetric [[a, b], [b, d]].

    Its eigenvalues are m +- h, and (ux, uy) is the unit eigenvector of m + h.
    """
    middle, half = 0.5 * (a + d), math.hypot(0.5 * (a - d), b)
    if b != 0.0:
        ux, uy = middle + half - d, b
        norm = math.sqrt(ux * ux + uy * uy)
        return middle, half, ux / norm, uy / norm
    if a >= d:
        return middle, half, 1.0, 0.0
    return middle, half, 0.0, 1.0



@kernel
def _register_pair(current, start, size, outline, first, count, gx0, gy0, reach, params,
                   result):
    """Register one smoothed chain onto another (rows of ``_smooth``; step 3).

    The chain is ``current[start:start + size]``, the outline ``outline[first:first +
    count]``; ``(gx0, gy0)``: d0; ``reach``: the first trim distance.  ``result`` (10,): d (2), H's
    ``xx, xy, yy``, the kept pairs k (0: failed, or H is 0), sigma^2, the whole windows of
    the smaller side, and the unit direction H does not measure ((0, 0) when it measures
    both).
    """
    result[:] = 0.0
    result[0], result[1] = gx0, gy0
    if count < 3 or size < 3:
        return
    outline = outline[first:first + count]
    current = current[start:start + size]
    trim, link = params[TRIM], params[LINK]
    whole_old = whole_new = 0
    windows = 0.0
    for j in range(count):
        whole_old += outline[j, 6] > 0.0
    for i in range(size):
        if current[i, 6] > 0.0:
            whole_new += 1
            windows += current[i, 5]
    result[7] = min(whole_old, whole_new)
    # Neighbouring centroids share most of their windows: pairing every stride-th one, each
    # weighted by the stride, measures about as well for a fraction of the work.
    stride = max(int(windows / max(whole_new, 1) / STRIDE), 1)
    dx, dy = gx0, gy0
    cut = max(reach, trim)
    axx = axy = ayy = lxx = lxy = lyy = rss = spread = 0.0
    kept = pairs = 0
    for _ in range(int(params[ITERATIONS])):
        axx = axy = ayy = gx = gy = lxx = lxy = lyy = rss = spread = 0.0
        kept = pairs = 0
        j = -1
        reach_sq = (cut + link) * (cut + link)
        for i in range(0, size, stride):
            if current[i, 6] == 0.0:
                continue
            x, y = current[i, 0] - dx, current[i, 1] - dy
            j, best = _nearest(outline, count, j, x, y, reach_sq)
            if best > reach_sq or outline[j, 6] == 0.0 or outline[j, 4] == 0.0:
                continue  # too far, or at (or beyond) the outline's ends
            tx, ty = outline[j, 2], outline[j, 3]
            r = (y - outline[j, 1]) * tx - (x - outline[j, 0]) * ty  # n . e, n = (-ty, tx)
            if abs(r) > cut:
                continue
            axx += stride * ty * ty
            axy -= stride * tx * ty
            ayy += stride * tx * tx
            gx -= stride * ty * r
            gy += stride * tx * r
            weight = stride / (outline[j, 4] * outline[j, 4])
            lxx += weight * tx * tx
            lxy += weight * tx * ty
            lyy += weight * ty * ty
            rss += r * r
            spread += 1.0 / current[i, 5] + 1.0 / outline[j, 5]
            kept += stride
            pairs += 1
        if pairs < 3:
            return
        bxx, byy = axx + RIDGE, ayy + RIDGE
        rx = gx - RIDGE * (dx - gx0)
        ry = gy - RIDGE * (dy - gy0)
        det = bxx * byy - axy * axy
        step_x = (byy * rx - axy * ry) / det
        step_y = (bxx * ry - axy * rx) / det
        dx += step_x
        dy += step_y
        final = cut <= trim
        cut = max(trim, 0.5 * cut)
        if final and step_x * step_x + step_y * step_y < 1.0e-8:  # under 0.1 mm
            break
    variance = max(params[POINT] ** 2, rss / spread * pairs / max(pairs - 2, 1))
    scale = LEAK * 2.0 * variance
    hxx, hxy, hyy = axx - scale * lxx, axy - scale * lxy, ayy - scale * lyy
    middle, half, ux, uy = _eigen(hxx, hxy, hyy)
    result[0], result[1] = dx, dy
    if middle + half < MIN_INFORMATION:
        return  # measures nothing
    result[2], result[3], result[4] = (middle + half) * ux * ux, (middle + half) * ux * uy, \
        (middle + half) * uy * uy
    if middle - half >= MIN_INFORMATION:
        result[2] += (middle - half) * uy * uy
        result[3] -= (middle - half) * ux * uy
        result[4] += (middle - half) * ux * ux
    else:
        result[8], result[9] = -uy, ux
    result[5], result[6] = kept, variance



@kernel(signature('void', F2, F2, F1, 'f8', F1, F1))
def register_outline(new, old, guess, reach, params, result):
    """Register the chain ``new`` onto the outline ``old`` from d0 = ``guess`` (step 3).

    ``params``: ``TrackerSettings.vector``; ``result`` (10,) as ``_register_pair``'s.
    """
    if params.shape[0] != PARAMETERS or result.shape[0] != 10 or new.shape[1] != 2 \
            or old.shape[1] != 2 or guess.shape[0] != 2:
        raise ValueError('register_outline: new and old must be (n, 2), guess (2,), params '
                         'TrackerSettings.vector(...), result (10,)')
    outline = np.empty((old.shape[0], 7))
    current = np.empty((new.shape[0], 7))
    sums = np.empty((max(old.shape[0], new.shape[0]) + 1, 2))
    _smooth(old, 0, old.shape[0], params[SPAN], outline, sums)
    _smooth(new, 0, new.shape[0], params[SPAN], current, sums)
    _register_pair(current, 0, new.shape[0], outline, 0, old.shape[0], guess[0], guess[1],
                   reach, params, result)



@kernel
def _gap_sq(box, track, gx, gy):
    """Return the squared gap between ``box`` and a track's box moved by (gx, gy).

    Boxes as ``_gate``'s ``stats`` rows and the per-track floats: low (x, y), high (x, y).
    """
    wx = max(max(box[0] - track[HIGH] - gx, track[LOW] + gx - box[2]), 0.0)
    wy = max(max(box[1] - track[HIGH + 1] - gy, track[LOW + 1] + gy - box[3]), 0.0)
    return wx * wx + wy * wy



@kernel(signature('UniTuple(i8, 2)', F2, I1, F2, F3, F2, 'i8', 'f8', F1, F2, B1, F2, I1, I1,
                  I1, I1, F1))
def _gate(points, starts, states, covariances, tracks, count, dt, params, stats, structure,
          cost, match, claimed, rows, columns, padded):
    """Run steps 1 and 2 up to the ambiguous pairs; return their (tracks R, clusters K).

    Fills ``stats`` (C, 6) (bounding box low, high, centroid per cluster), ``structure``
    (C,), predicts the ``count`` tracks, fills ``cost`` (count, C) (FAR outside the gate, or
    between structure and a track whose last cluster was not, or the other way round),
    ``match`` (count,) / ``claimed`` (C,): the partner of a unique pair, else -1; and for
    the ambiguous ones their indices ``rows[:R]``, ``columns[:K]`` and the (R + K)^2
    row-major matrix ``padded`` for ``linear_sum_assignment``: squared costs, ``gate^2`` on
    the diagonals of the off blocks (unpaired), FAR^2 elsewhere, 0 in the corner block.
    Returns (-1, 0) and does nothing else when a cluster is empty or a point not finite.
    """
    clusters = starts.shape[0] - 1
    for c in range(clusters):
        if starts[c + 1] <= starts[c]:
            return -1, 0
    for i in range(points.shape[0]):
        if not (math.isfinite(points[i, 0]) and math.isfinite(points[i, 1])):
            return -1, 0
    extent_sq = params[EXTENT] * params[EXTENT]
    for c in range(clusters):
        lx = hx = points[starts[c], 0]
        ly = hy = points[starts[c], 1]
        sx = sy = 0.0
        for i in range(starts[c], starts[c + 1]):
            x, y = points[i, 0], points[i, 1]
            lx, hx, ly, hy = min(lx, x), max(hx, x), min(ly, y), max(hy, y)
            sx += x
            sy += y
        size = starts[c + 1] - starts[c]
        stats[c, 0], stats[c, 1], stats[c, 2], stats[c, 3] = lx, ly, hx, hy
        stats[c, 4], stats[c, 5] = sx / size, sy / size
        structure[c] = (hx - lx) ** 2 + (hy - ly) ** 2 > extent_sq
        claimed[c] = 0
    q = params[ACCEL] * params[ACCEL]
    gate_sq = params[GATE] * params[GATE]
    for t in range(count):
        predict_one(states[t], covariances[t], dt, q)
        track = tracks[t]
        gx, gy = states[t, 0] - states[t, 4], states[t, 1] - states[t, 5]
        large = ((track[HIGH] - track[LOW]) ** 2
                 + (track[HIGH + 1] - track[LOW + 1]) ** 2 > extent_sq)
        match[t] = 0
        for c in range(clusters):
            if structure[c] != large:
                cost[t, c] = FAR  # structure pairs with structure only
                continue
            if _gap_sq(stats[c], track, gx, gy) <= gate_sq:
                cost[t, c] = 0.5 * (math.hypot(stats[c, 0] - track[LOW] - gx,
                                               stats[c, 1] - track[LOW + 1] - gy)
                                    + math.hypot(stats[c, 2] - track[HIGH] - gx,
                                                 stats[c, 3] - track[HIGH + 1] - gy))
                match[t] += 1
                claimed[c] += 1
            else:
                cost[t, c] = FAR
    ambiguous = 0
    for t in range(count):
        candidates = match[t]
        match[t] = -1
        if candidates == 0:
            continue
        if candidates == 1:
            for c in range(clusters):
                if cost[t, c] < FAR and claimed[c] == 1:
                    match[t] = c
                    claimed[c] = -3 - t  # paired; decoded below
        if match[t] == -1:
            rows[ambiguous] = t
            ambiguous += 1
    width = 0
    for c in range(clusters):
        if claimed[c] <= -3:
            claimed[c] = -3 - claimed[c]
        elif claimed[c] == 0:
            claimed[c] = -1
        else:
            claimed[c] = -1
            columns[width] = c
            width += 1
    size = ambiguous + width
    alone, far = params[GATE] * params[GATE], FAR * FAR
    for i in range(size):
        for j in range(size):
            if i < ambiguous and j < width:
                value = cost[rows[i], columns[j]] ** 2
            elif i < ambiguous:
                value = alone if j - width == i else far
            elif j < width:
                value = alone if i - ambiguous == j else far
            else:
                value = 0.0
            padded[i * size + j] = value
    return ambiguous, width



@kernel(signature('void', I1, I1, I1, I1, 'i8', 'i8', F1, I1, I1))
def _assign(chosen_rows, chosen_columns, rows, columns, ambiguous, width, padded, match,
            claimed):
    """Apply ``linear_sum_assignment``'s answer on ``_gate``'s padded matrix (step 2)."""
    size = ambiguous + width
    for k in range(chosen_rows.shape[0]):
        i, j = chosen_rows[k], chosen_columns[k]
        if i < ambiguous and j < width and padded[i * size + j] < FAR * FAR:
            match[rows[i]] = columns[j]
            claimed[columns[j]] = rows[i]



@kernel
def _known_velocity(state, P, limit):
    """Return the filter's velocity without its components whose std exceeds ``limit``.

    The velocity block ``P_vv = [[a, b], [b, d]]`` has eigenvalues ``(a + d) / 2 +- sqrt(((a
    - d) / 2)^2 + b^2)``; the velocity's component along each eigenvector whose eigenvalue
    exceeds ``limit^2`` is removed.
    """
    middle, half, ux, uy = _eigen(P[2, 2], P[2, 3], P[3, 3])
    vx, vy = state[2], state[3]
    limit_sq = limit * limit
    if middle + half > limit_sq:
        along = vx * ux + vy * uy
        vx, vy = vx - along * ux, vy - along * uy
    if middle - half > limit_sq:
        along = -vx * uy + vy * ux
        vx, vy = vx + along * uy, vy - along * ux
    return vx, vy



@kernel
def _classify(state, P, track, params, registered, evidence):
    """Step 4 for a matched track: count passes and flip ``track[MOVING]``.

    A failed registration (``registered`` false) does not pass, nor, while the track
    stands, one without ``evidence`` that its cluster moved (``ScanTracker.update``).
    """
    vx, vy = _known_velocity(state, P, params[KNOWN])
    speed_sq = vx * vx + vy * vy
    along_sq = vx * vx * P[2, 2] + 2.0 * vx * vy * P[2, 3] + vy * vy * P[3, 3]
    passes = (registered and (evidence or track[MOVING] == 1)
              and speed_sq > params[MOVING_SPEED] ** 2
              and speed_sq * speed_sq > params[SIGMAS] ** 2 * along_sq)
    if passes != (track[MOVING] == 1):
        track[STREAK] += 1
    else:
        track[STREAK] = 0
    if track[STREAK] >= params[SCANS]:
        track[MOVING] = 1 - track[MOVING]
        track[STREAK] = 0



@kernel
def _measure(smoothed, starts, c, box, storage, state, P, floats, ints, params, H, result,
             other, scratch):
    """Register cluster c onto the track's outline and update its filter (step 3).

    ``smoothed``: the cluster's rows of ``_smooth``; ``box``: its bounding box; ``storage``:
    the outline's rows.  When the predicted displacement is uncertain (its std above
    ``trim``: a young track) the registration also starts from the shift of the boxes'
    centres and the start that keeps more pairs wins.  Return whether the registration
    succeeded.  Either way the clone restarts at the track's position, for the cluster's
    points are its next outline.
    """
    gx, gy = state[0] - state[4], state[1] - state[5]
    spread = P[0, 0] + P[1, 1] - 2.0 * (P[0, 4] + P[1, 5]) + P[4, 4] + P[5, 5]
    reach = min(params[TRIM] + 3.0 * math.sqrt(max(spread, 0.0)), params[GATE])
    size = starts[c + 1] - starts[c]
    _register_pair(smoothed, starts[c], size, storage, ints[FIRST], ints[SIZE], gx, gy, reach,
                   params, result)
    if spread > params[TRIM] ** 2:
        bx = 0.5 * (box[0] + box[2] - floats[LOW] - floats[HIGH])
        by = 0.5 * (box[1] + box[3] - floats[LOW + 1] - floats[HIGH + 1])
        _register_pair(smoothed, starts[c], size, storage, ints[FIRST], ints[SIZE], bx, by,
                       reach, params, other)
        if other[5] > result[5] or (other[5] == result[5] and other[6] < result[6]):
            result[:] = other
    if result[5] > 0.0 and result[0] * result[0] + result[1] * result[1] > params[TRIM] ** 2:
        _register_pair(smoothed, starts[c], size, storage, ints[FIRST], ints[SIZE], 0.0, 0.0,
                       params[TRIM], params, other)
        if other[5] >= result[5] and other[6] <= REST_VARIANCE * result[6]:
            result[:] = other
    kept = result[5]
    good = kept >= 3 and kept >= params[OVERLAP] * result[7]
    if good:
        hxx, hxy, hyy, variance = result[2] + RIDGE, result[3], result[4] + RIDGE, result[6]
        det = hxx * hyy - hxy * hxy
        # The two scans' pose errors (``pose_std``, ``heading_std`` at the cluster's range).
        rx, ry = box[4] - params[ORIGIN_X], box[5] - params[ORIGIN_Y]
        pose = 2.0 * (params[POSE] ** 2 + (rx * rx + ry * ry) * params[HEADING] ** 2)
        update_one(state, P, H, result[0] - gx, result[1] - gy, variance * hyy / det + pose,
                   -variance * hxy / det, variance * hxx / det + pose, result[8], result[9],
                   scratch)
    reclone_one(state, P)
    return good



@kernel
def _beside_a_mover(box, states, floats, ints, count, gap):
    """Return True when ``box`` lies within ``gap`` of a moving track's predicted box.

    The first ``count`` tracks, their boxes moved by ``p - c`` (0 for those the scan matched,
    whose clone has restarted).  A cluster born there may be an object that was hidden
    behind or inside the mover (``scan_tracker``, step 5).
    """
    gap_sq = gap * gap
    for t in range(count):
        if ints[t, MOVING] != 1:
            continue
        if _gap_sq(box, floats[t], states[t, 0] - states[t, 4],
                   states[t, 1] - states[t, 5]) <= gap_sq:
            return True
    return False



@kernel(signature('UniTuple(i8, 2)', F2, I1, F2, B1, B1, I1, I1, F2, F3, F2, I2, 'i8', 'f8',
                  F1, F2, F2, I1, F2, B2, I1))
def _advance(points, starts, stats, structure, evidence, match, claimed, states, covariances,
             floats, ints, count, stamp, params, storage, new_storage, next_id, out, flags,
             ids):
    """Run steps 3 and 4, births, deletion and outlines; return (tracks, outline rows).

    Arrays as ``_gate``'s, plus per cluster ``evidence`` that it moved (``_classify``), the
    per-track ``floats`` and ``ints`` (capacity at least
    ``count`` + clusters), the smoothed outlines' ``storage`` and ``new_storage`` (7
    columns, rows at least ``len(points) + len(storage)``; structure tracks keep none),
    ``next_id`` (1,); per cluster ``out`` (C, 3): the published velocity and the worst-axis
    velocity standard deviation, ``flags`` (C, 5): confirmed, moving, published, trusted,
    moved lately (within ``DISTRUST`` s; never structure), and ``ids`` (C,).  Every
    cluster but structure is smoothed once, here.  A track's trusted streak counts its
    successive registrations that paired at least ``SHARE`` of the cluster's whole
    windows (anything else, a failed registration included, ends it).
    A track that has not been moving (``_classify``) for ``DISTRUST`` s is trusted; one
    that has is trusted while its streak is ``TRUSTED`` or more.  A track born within
    ``BESIDE`` of a moving track's predicted box counts as moving at birth
    (``_beside_a_mover``).
    """
    clusters = starts.shape[0] - 1
    smoothed = np.empty((points.shape[0], 7))
    widest = 0
    for c in range(clusters):
        widest = max(widest, starts[c + 1] - starts[c])
    sums = np.empty((widest + 1, 2))
    for c in range(clusters):
        if not structure[c]:
            _smooth(points, starts[c], starts[c + 1] - starts[c], params[SPAN],
                    smoothed[starts[c]:], sums)
    result = np.empty(10)
    other = np.empty(10)
    scratch = np.empty((18, 6))
    relative = np.zeros((2, 6))  # H of a displacement, p - c
    relative[0, 0] = relative[1, 1] = 1.0
    relative[0, 4] = relative[1, 5] = -1.0
    for t in range(count):
        c = match[t]
        if c < 0:
            continue
        if not structure[c]:
            registered = _measure(smoothed, starts, c, stats[c], storage, states[t],
                                  covariances[t], floats[t], ints[t], params, relative,
                                  result, other, scratch)
            ints[t, HITS] += registered
            whole = 0
            for i in range(starts[c], starts[c + 1]):
                whole += smoothed[i, 6] > 0.0
            explained = registered and result[5] >= params[SHARE] * whole
            ints[t, TRUST] = ints[t, TRUST] + 1 if explained else 0
            _classify(states[t], covariances[t], ints[t], params, registered, evidence[c])
        else:
            reclone_one(states[t], covariances[t])
            ints[t, MOVING] = ints[t, STREAK] = 0
        floats[t, SEEN] = stamp
        if ints[t, MOVING] == 1:
            floats[t, MOVED] = stamp
        for k in range(6):
            floats[t, LOW + k] = stats[c, k]
    total = count
    for c in range(clusters):
        if claimed[c] >= 0:
            continue
        claimed[c] = total
        states[total, :] = 0.0
        states[total, 0], states[total, 1] = stats[c, 4], stats[c, 5]
        covariances[total, :, :] = 0.0
        covariances[total, 0, 0] = covariances[total, 1, 1] = params[POINT] ** 2
        covariances[total, 2, 2] = covariances[total, 3, 3] = params[SPEED] ** 2
        reclone_one(states[total], covariances[total])
        for k in range(6):
            floats[total, LOW + k] = stats[c, k]
        floats[total, SEEN] = stamp
        beside = _beside_a_mover(stats[c], states, floats, ints, count, params[BESIDE])
        floats[total, MOVED] = stamp if beside else -np.inf
        ints[total, :] = 0
        ints[total, ID] = next_id[0]
        ints[total, HITS] = 1
        next_id[0] += 1
        total += 1
    row_cluster = np.full(total, -1)
    for c in range(clusters):
        row_cluster[claimed[c]] = c
    kept = used = 0
    for t in range(total):
        c = row_cluster[t]
        if c < 0 and stamp - floats[t, SEEN] > params[COAST]:
            continue
        if kept != t:
            states[kept, :] = states[t, :]
            covariances[kept, :, :] = covariances[t, :, :]
            floats[kept, :] = floats[t, :]
            ints[kept, :] = ints[t, :]
        if c >= 0:
            size = 0 if structure[c] else starts[c + 1] - starts[c]
            new_storage[used:used + size, :] = smoothed[starts[c]:starts[c] + size, :]
            claimed[c] = kept
        else:
            size = ints[kept, SIZE]
            first = ints[kept, FIRST]
            new_storage[used:used + size, :] = storage[first:first + size, :]
        ints[kept, FIRST], ints[kept, SIZE] = used, size
        used += size
        kept += 1
    for c in range(clusters):
        t = claimed[c]
        P = covariances[t]
        a, b, d = P[2, 2], P[2, 3], P[3, 3]
        out[c, 2] = math.sqrt(max(0.5 * (a + d) + math.hypot(0.5 * (a - d), b), 0.0))
        confirmed = ints[t, HITS] >= params[CONFIRM]
        moving = ints[t, MOVING] == 1 and not structure[c]
        published = confirmed and moving
        vx, vy = _known_velocity(states[t], P, params[KNOWN])
        out[c, 0] = vx if published else 0.0
        out[c, 1] = vy if published else 0.0
        lately = not structure[c] and stamp - floats[t, MOVED] <= params[DISTRUST]
        flags[c, 0], flags[c, 1], flags[c, 2] = confirmed, moving, published
        flags[c, 3] = not lately or ints[t, TRUST] >= params[TRUSTED]
        flags[c, 4] = lately
        ids[c] = ints[t, ID]
    return kept, used



@kernel
def predict_one(state, P, dt, q):
    """Predict one state in place (4 or 6 entries, ``P`` square, ``q = accel_std^2``).

    ``F P F^T`` as two passes, rows then columns: ``P[i] += dt P[i + 2]`` for the position
    rows i = 0, 1, then the same for the columns; then Q is added to the [p, v] block.
    """
    size = state.shape[0]
    state[0] += dt * state[2]
    state[1] += dt * state[3]
    for i in range(2):
        for j in range(size):
            P[i, j] += dt * P[i + 2, j]
    for i in range(size):
        for j in range(2):
            P[i, j] += dt * P[i, j + 2]
    for i in range(2):
        P[i, i] += q * dt * dt * dt / 3.0
        P[i, 2 + i] += q * dt * dt / 2.0
        P[2 + i, i] += q * dt * dt / 2.0
        P[2 + i, 2 + i] += q * dt



@kernel
def update_one(state, P, H, y0, y1, r00, r01, r11, wx, wy, scratch):
    """Update one state in place with innovation (y0, y1) of ``z = H x + v`` (``H`` (2, n)).

    As ``_linear_update`` (Joseph form, symmetrised), R = [[r00, r01], [r01, r11]], with
    ``free = (wx, wy)`` unless that is (0, 0); ``S^-1`` is the closed-form inverse of the
    2 x 2 S.  ``scratch``: (3 n, n) work space.
    """
    size = state.shape[0]
    gain, reduce, product = scratch[0:size], scratch[size:2 * size], scratch[2 * size:]
    for i in range(size):  # P H^T into gain's two columns
        gain[i, 0] = gain[i, 1] = 0.0
        for k in range(size):
            gain[i, 0] += P[i, k] * H[0, k]
            gain[i, 1] += P[i, k] * H[1, k]
    s00, s01, s11 = r00, r01, r11
    for k in range(size):
        s00 += H[0, k] * gain[k, 0]
        s01 += 0.5 * (H[0, k] * gain[k, 1] + H[1, k] * gain[k, 0])
        s11 += H[1, k] * gain[k, 1]
    det = s00 * s11 - s01 * s01
    i00, i01, i11 = s11 / det, -s01 / det, s00 / det
    for i in range(size):
        a, b = gain[i, 0], gain[i, 1]
        gain[i, 0], gain[i, 1] = a * i00 + b * i01, a * i01 + b * i11
    if wx != 0.0 or wy != 0.0:
        for i in range(0, size, 2):
            for column in range(2):
                along = gain[i, column] * wx + gain[i + 1, column] * wy
                gain[i, column] -= along * wx
                gain[i + 1, column] -= along * wy
    for i in range(size):
        state[i] += gain[i, 0] * y0 + gain[i, 1] * y1
        for j in range(size):
            reduce[i, j] = (1.0 if i == j else 0.0) - gain[i, 0] * H[0, j] - gain[i, 1] * H[1, j]
    for i in range(size):
        for j in range(size):
            total = 0.0
            for k in range(size):
                total += reduce[i, k] * P[k, j]
            product[i, j] = total
    for i in range(size):
        for j in range(i, size):
            total = 0.0
            for k in range(size):
                total += product[i, k] * reduce[j, k]
            total += (gain[i, 0] * (r00 * gain[j, 0] + r01 * gain[j, 1])
                      + gain[i, 1] * (r01 * gain[j, 0] + r11 * gain[j, 1]))
            P[i, j] = total
    for i in range(size):
        for j in range(i):
            P[i, j] = P[j, i]



@kernel
def reclone_one(state, P):
    """Set the clone (entries 4, 5) of a 6-entry state to its position, in place."""
    state[4], state[5] = state[0], state[1]
    for i in range(2):
        for j in range(6):
            P[4 + i, j] = P[i, j]
    for i in range(6):
        for j in range(2):
            P[i, 4 + j] = P[i, j]
    for i in range(2):
        for j in range(2):
            P[4 + i, 4 + j] = P[i, j]



@kernel(signature('void', F2, F3, 'f8', 'f8'))
def predict_all(states, covariances, dt, accel_std):
    """Predict every track (rows of ``states`` (T, n), ``covariances`` (T, n, n)) in place."""
    for t in range(states.shape[0]):
        predict_one(states[t], covariances[t], dt, accel_std * accel_std)



@kernel(signature('void', F2, F3, I1, F2, F3))
def update_rows(states, covariances, rows, measurements, noises):
    """Update track ``rows[m]`` with position ``measurements[m]``, covariance ``noises[m]``."""
    size = states.shape[1]
    scratch = np.empty((3 * size, size))
    H = np.zeros((2, size))
    H[0, 0] = H[1, 1] = 1.0
    for m in range(rows.shape[0]):
        state, R = states[rows[m]], noises[m]
        update_one(state, covariances[rows[m]], H, measurements[m, 0] - state[0],
                   measurements[m, 1] - state[1], R[0, 0], 0.5 * (R[0, 1] + R[1, 0]),
                   R[1, 1], 0.0, 0.0, scratch)
