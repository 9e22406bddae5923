"""Compiled keypoint detection: FAST corners, their orientation, and ORB-SLAM's quadtree.

- ``fast_corners``: FAST-9 on the 16-pixel circle with OpenCV's score and 3 x 3 non-maximum
  suppression, returned as arrays. OpenCV's detector (the reference, ``features.corners``)
  gives the same corners and scores, but as Python objects: 2.9 ms for the ~14,000 corners of
  a 640 x 480 pyramid at threshold 7, twice what finding them costs here.
- ``moments``: the intensity centroid of each kept keypoint's disc (ORB's orientation), for
  the ~1,000 the quadtree keeps rather than the 10,000 candidates OpenCV's ORB orients.
- ``distribute``: DistributeOctTree as one loop (``features.distribute_numpy`` is the
  reference, equal to it index for index). The level's candidates are split into a quadtree
  until it has as many leaves as the level wants keypoints, and each leaf keeps its strongest
  corner. The reference walks Python lists of nodes; here each node is a run of one index
  array, split in place, stable.
"""

from __future__ import annotations

import math

import numpy as np
from depotbench.core.jit import jit

CIRCLE_DX = np.array([0, 1, 2, 3, 3, 3, 2, 1, 0, -1, -2, -3, -3, -3, -2, -1], np.int64)
CIRCLE_DY = np.array([-3, -3, -2, -1, 0, 1, 2, 3, 3, 3, 2, 1, 0, -1, -2, -3], np.int64)
"""FAST's circle: the 16 pixels at distance 3 (Bresenham), in order around it."""

NODES_PER_CANDIDATE = 16
"""Room for nodes, per candidate: a pass makes at most one node per candidate it splits, and
a level ends within ~5 passes (4^5 leaves exceed any level's share); a full store stops the
splitting, which ``test_kernels`` shows never happens on its draws."""


@jit
def _divide(node, ulx, uly, urx, bly, start, count, alive, perm, buffer, xs, ys, n_nodes):
    """ExtractorNode::DivideNode: the node's four quadrants (ceil of half its sides), its keys
    split among them in their order; empty quadrants are dropped. Returns (children made,
    nodes now), the children being the last ``made`` nodes."""
    midx = ulx[node] + int(math.ceil((urx[node] - ulx[node]) / 2.0))
    midy = uly[node] + int(math.ceil((bly[node] - uly[node]) / 2.0))
    first, n_keys = start[node], count[node]
    sizes = np.zeros(4, np.int64)
    for i in range(first, first + n_keys):
        k = perm[i]
        q = (0 if ys[k] < midy else 2) if xs[k] < midx else (1 if ys[k] < midy else 3)
        sizes[q] += 1
    offsets = np.zeros(4, np.int64)
    for q in range(1, 4):
        offsets[q] = offsets[q - 1] + sizes[q - 1]
    fill = offsets.copy()
    for i in range(first, first + n_keys):
        k = perm[i]
        q = (0 if ys[k] < midy else 2) if xs[k] < midx else (1 if ys[k] < midy else 3)
        buffer[first + fill[q]] = k
        fill[q] += 1
    for i in range(first, first + n_keys):
        perm[i] = buffer[i]
    alive[node] = False
    made = 0
    for q in range(4):
        if sizes[q] == 0:
            continue
        s = n_nodes + made
        ulx[s] = ulx[node] if q % 2 == 0 else midx
        urx[s] = midx if q % 2 == 0 else urx[node]
        uly[s] = uly[node] if q < 2 else midy
        bly[s] = midy if q < 2 else bly[node]
        start[s], count[s] = first + offsets[q], sizes[q]
        alive[s] = True
        made += 1
    return made, n_nodes + made


@jit
def distribute(
    xs: np.ndarray, ys: np.ndarray, response: np.ndarray, width: int, height: int, wanted: int
) -> np.ndarray:
    """``features.distribute_numpy``: the indices (ascending) of the candidates kept."""
    n = len(xs)
    if n == 0 or wanted <= 0:
        return np.zeros(0, np.int64)
    n_ini = max(int(math.floor(width / height + 0.5)), 1)
    hx = width / n_ini
    cap = NODES_PER_CANDIDATE * n + n_ini + 16
    ulx = np.empty(cap, np.int64)
    uly = np.empty(cap, np.int64)
    urx = np.empty(cap, np.int64)
    bly = np.empty(cap, np.int64)
    start = np.empty(cap, np.int64)
    count = np.empty(cap, np.int64)
    alive = np.zeros(cap, np.bool_)
    active = np.empty(cap, np.int64)
    expand = np.empty(cap, np.int64)
    perm = np.empty(n, np.int64)
    buffer = np.empty(n, np.int64)
    column = np.empty(n, np.int64)
    sizes = np.zeros(n_ini, np.int64)
    for k in range(n):
        column[k] = min(int(xs[k] / hx), n_ini - 1)
        sizes[column[k]] += 1
    firsts = np.zeros(n_ini, np.int64)
    for c in range(1, n_ini):
        firsts[c] = firsts[c - 1] + sizes[c - 1]
    fill = firsts.copy()
    for k in range(n):
        perm[fill[column[k]]] = k
        fill[column[k]] += 1
    n_active = 0
    for c in range(n_ini):
        if sizes[c] > 0:
            ulx[n_active], uly[n_active] = int(hx * c), 0
            urx[n_active], bly[n_active] = int(hx * (c + 1)), height
            start[n_active], count[n_active] = firsts[c], sizes[c]
            alive[n_active] = True
            active[n_active] = n_active
            n_active += 1
    n_nodes = n_active
    n_live = n_active
    finished = False
    while not finished:
        previous = n_live
        n_expand = 0
        for i in range(n_active):  # every node of more than one key, once
            node = active[i]
            if count[node] == 1 or n_nodes + 4 >= cap:
                continue
            made, n_nodes = _divide(
                node, ulx, uly, urx, bly, start, count, alive, perm, buffer, xs, ys, n_nodes
            )
            n_live += made - 1
            n_expand = _splittable(count, n_nodes - made, n_nodes, expand, n_expand)
        n_active = _gather(active, alive, n_nodes)
        if n_live >= wanted or n_live == previous:
            finished = True
        elif n_live + 3 * n_expand > wanted:
            while not finished:  # split the biggest nodes first until the level has enough
                previous = n_live
                candidates = expand[:n_expand].copy()
                key = count[candidates] * float(1 << 20) + ulx[candidates]
                order = np.argsort(key, kind="mergesort")
                n_expand = 0
                for j in range(len(order) - 1, -1, -1):
                    if n_nodes + 4 >= cap:
                        break
                    node = candidates[order[j]]
                    made, n_nodes = _divide(
                        node, ulx, uly, urx, bly, start, count, alive, perm, buffer, xs, ys, n_nodes
                    )
                    n_live += made - 1
                    n_expand = _splittable(count, n_nodes - made, n_nodes, expand, n_expand)
                    if n_live >= wanted:
                        break
                if n_live >= wanted or n_live == previous:
                    finished = True
            n_active = _gather(active, alive, n_nodes)
    kept = np.empty(n_active, np.int64)
    for i in range(n_active):
        node = active[i]
        best = perm[start[node]]
        for j in range(start[node] + 1, start[node] + count[node]):
            if response[perm[j]] > response[best] or (response[perm[j]] == response[best] and perm[j] < best):
                best = perm[j]
        kept[i] = best
    return np.sort(kept)


@jit
def _splittable(count, first, last, expand, n_expand):
    """Append the nodes first..last-1 holding more than one candidate to ``expand``."""
    for node in range(first, last):
        if count[node] > 1:
            expand[n_expand] = node
            n_expand += 1
    return n_expand


@jit
def _gather(active, alive, n_nodes):
    """The live nodes, in the order they were made."""
    n_active = 0
    for node in range(n_nodes):
        if alive[node]:
            active[n_active] = node
            n_active += 1
    return n_active


@jit
def fast_corners(image, threshold, border):
    """FAST-9 corners of a uint8 image at least ``border`` (3 or more) pixels inside its edges,
    each kept where its score beats its 8 neighbours' (a pixel that is no corner scores 0):
    columns, rows and scores, row by row. The score is the largest threshold at which the
    pixel would still be a corner, less 1 (OpenCV's, which ORB ranks by)."""
    rows, cols = image.shape
    score = np.zeros((rows, cols), np.int16)
    x0, x1 = max(3, border - 1), min(cols - 3, cols - border + 1)  # scored: one more on each side
    y0, y1 = max(3, border - 1), min(rows - 3, rows - border + 1)
    n = max(x1 - x0, 0)
    words = (n + 7) // 8  # the flags are scanned 8 at a time: most are 0
    flags = np.zeros(8 * words, np.uint8)
    brighter = np.zeros(n, np.uint8)
    darker = np.zeros(n, np.uint8)
    flat = image.ravel()
    offsets = CIRCLE_DY * cols + CIRCLE_DX
    d = np.empty(16, np.int32)
    runs = np.empty((2, 16), np.int32)
    corners = 0
    for y in range(y0, y1):
        _bounds(image[y, x0:x1], threshold, brighter, darker)
        _row_flags(image[y - 3 : y + 4, x0 - 3 : x1 + 3], brighter, darker, flags[:n])
        packed = flags.view(np.uint64)
        for word in range(words):
            if packed[word] == 0:
                continue
            for i in range(8 * word, 8 * word + 8):
                if flags[i] == 0:
                    continue
                centre = y * cols + x0 + i
                v = np.int32(flat[np.uint64(centre)])
                sign = 1 if flags[i] == 2 else -1  # 2: the arc is darker than the centre
                for k in range(16):
                    d[k] = sign * (v - np.int32(flat[np.uint64(centre + offsets[k])]))
                score[y, x0 + i] = _best_arc(d, runs) - 1
                corners += 1
    xs = np.empty(corners, np.int64)
    ys = np.empty(corners, np.int64)
    scores = np.empty(corners, np.int32)
    m = max(cols - 2 * border, 0)
    words = (m + 7) // 8
    keep = np.zeros(8 * words, np.bool_)
    found = 0
    for y in range(border, rows - border):
        _row_maxima(score[y - 1, border - 1 :], score[y, border - 1 :], score[y + 1, border - 1 :], keep[:m])
        packed = keep.view(np.uint64)
        for word in range(words):
            if packed[word] == 0:
                continue
            for i in range(8 * word, 8 * word + 8):
                if keep[i]:
                    xs[found], ys[found], scores[found] = border + i, y, score[y, border + i]
                    found += 1
    return xs[:found], ys[:found], scores[:found]


@jit
def _bounds(row, threshold, brighter, darker):
    """Per pixel, the values a circle pixel must exceed (or fall below) to count, saturated at
    0 and 255 so that the comparisons stay in bytes."""
    for i in range(len(row)):
        v = np.int32(row[i])
        brighter[i] = np.uint8(min(v + threshold, 255))
        darker[i] = np.uint8(max(v - threshold, 0))


@jit
def _row_flags(window, brighter, darker, flags):
    """One row's corner test, branch-free so that it runs 64 pixels a vector: bit 1 where 9
    circle pixels in a row are brighter, bit 2 where 9 are darker. ``window`` holds the row
    with 3 rows and 3 columns more on each side; pixel i sits at window[3, i + 3]."""
    for i in range(len(flags)):
        hi, lo = brighter[i], darker[i]
        p0, p1, p2, p3 = window[0, i + 3], window[0, i + 4], window[1, i + 5], window[2, i + 6]
        p4, p5, p6, p7 = window[3, i + 6], window[4, i + 6], window[5, i + 5], window[6, i + 4]
        p8, p9, p10, p11 = window[6, i + 3], window[6, i + 2], window[5, i + 1], window[4, i]
        p12, p13, p14, p15 = window[3, i], window[2, i], window[1, i + 1], window[0, i + 2]
        bright = _nine_in_a_row(
            p0 > hi, p1 > hi, p2 > hi, p3 > hi, p4 > hi, p5 > hi, p6 > hi, p7 > hi,
            p8 > hi, p9 > hi, p10 > hi, p11 > hi, p12 > hi, p13 > hi, p14 > hi, p15 > hi,
        )  # fmt: skip
        dark = _nine_in_a_row(
            p0 < lo, p1 < lo, p2 < lo, p3 < lo, p4 < lo, p5 < lo, p6 < lo, p7 < lo,
            p8 < lo, p9 < lo, p10 < lo, p11 < lo, p12 < lo, p13 < lo, p14 < lo, p15 < lo,
        )  # fmt: skip
        flags[i] = np.uint8(bright) | (np.uint8(dark) << np.uint8(1))


@jit
def _nine_in_a_row(k0, k1, k2, k3, k4, k5, k6, k7, k8, k9, k10, k11, k12, k13, k14, k15):
    """Whether 9 of the 16 flags around the circle are set in a row: pairs, then fours, then
    eights of set flags, each eight followed by one more."""
    c0, c1, c2, c3, c4, c5, c6, c7 = k0 & k1, k1 & k2, k2 & k3, k3 & k4, k4 & k5, k5 & k6, k6 & k7, k7 & k8
    c8, c9, c10, c11 = k8 & k9, k9 & k10, k10 & k11, k11 & k12
    c12, c13, c14, c15 = k12 & k13, k13 & k14, k14 & k15, k15 & k0
    e0, e1, e2, e3, e4, e5, e6, e7 = c0 & c2, c1 & c3, c2 & c4, c3 & c5, c4 & c6, c5 & c7, c6 & c8, c7 & c9
    e8, e9, e10, e11 = c8 & c10, c9 & c11, c10 & c12, c11 & c13
    e12, e13, e14, e15 = c12 & c14, c13 & c15, c14 & c0, c15 & c1
    return (
        (e0 & e4 & k8) | (e1 & e5 & k9) | (e2 & e6 & k10) | (e3 & e7 & k11)
        | (e4 & e8 & k12) | (e5 & e9 & k13) | (e6 & e10 & k14) | (e7 & e11 & k15)
        | (e8 & e12 & k0) | (e9 & e13 & k1) | (e10 & e14 & k2) | (e11 & e15 & k3)
        | (e12 & e0 & k4) | (e13 & e1 & k5) | (e14 & e2 & k6) | (e15 & e3 & k7)
    )  # fmt: skip


@jit
def _best_arc(d, runs):
    """The largest minimum over 9 circle values in a row (minima of 2, then 4, then 8 and one
    more); ``runs`` is scratch."""
    for k in range(16):
        runs[0, k] = min(d[k], d[(k + 1) & 15])
    for k in range(16):
        runs[1, k] = min(runs[0, k], runs[0, (k + 2) & 15])
    best = np.int32(-256)
    for k in range(16):
        best = max(best, min(runs[1, k], runs[1, (k + 4) & 15], d[(k + 8) & 15]))
    return best


@jit
def _row_maxima(above, row, below, keep):
    """keep[i]: row[i + 1] is a corner scoring more than each of its 8 neighbours (the three
    rows start one column to the left)."""
    for i in range(len(keep)):
        s = row[i + 1]
        keep[i] = (
            (s > 0) & (s > above[i]) & (s > above[i + 1]) & (s > above[i + 2])
            & (s > row[i]) & (s > row[i + 2]) & (s > below[i]) & (s > below[i + 1]) & (s > below[i + 2])
        )  # fmt: skip


@jit
def moments(image, xs, ys, half_widths):
    """ORB's intensity centroid: per keypoint, the first moments (m10, m01) of the disc whose
    row v reaches ``half_widths[|v|]`` pixels either side of the centre. Rows are taken as
    views from their left end, so that every index is non-negative (Numba then neither
    checks for negative indices nor stops vectorising)."""
    n, radius = len(xs), len(half_widths) - 1
    m10 = np.zeros(n, np.int64)
    m01 = np.zeros(n, np.int64)
    for i in range(n):
        x, y = xs[i], ys[i]
        centre = image[y, x - radius : x + radius + 1]
        a, b = 0, 0
        for j in range(2 * radius + 1):
            a += (j - radius) * np.int64(centre[j])
        for v in range(1, radius + 1):
            w = half_widths[v]
            below, above = image[y + v, x - w : x + w + 1], image[y - v, x - w : x + w + 1]
            for j in range(2 * w + 1):
                p, q = np.int64(below[j]), np.int64(above[j])
                a += (j - w) * (p + q)
                b += v * (p - q)
        m10[i], m01[i] = a, b
    return m10, m01
