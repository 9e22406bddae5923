"""Compiled keypoint detection: FAST corners, their orientation, and ORB-SLAM's quadtree.

- ``fast_corners``: FAST-9 on the 16-pixel circle with OpenCV's score and 3 x 3 non-maximum
  suppression, returned as arrays. OpenCV's detector (the reference, ``features.corners``)
  gives the same corners and scores, but as Python objects: 4.7 ms for the ~12,000 corners of
  a noisy (``tum`` sensor) 640 x 480 pyramid at threshold 7, 2.2 ms here.
- ``moments``: the intensity centroid of each kept keypoint's disc (ORB's orientation), for
  the ~1,000 the quadtree keeps rather than the 10,000 candidates OpenCV's ORB orients.
- ``distribute``: DistributeOctTree as one loop (``features.distribute_numpy`` is the
  reference, equal to it index for index). The level's candidates are split into a quadtree
  until it has as many leaves as the level wants keypoints, and each leaf keeps its strongest
  corner. The reference walks Python lists of nodes; here each node is a run of one index
  array, split in place, stable.
- ``describe``: ORB's descriptor of the kept keypoints on the bench's own pyramid, blurred once
  (OpenCV's ``ORB.compute``, the reference, builds and blurs a pyramid of its own each frame
  and takes the keypoints as Python objects: 2.8 ms for the ~1,000 keypoints of a `tum` frame
  against 1.5 here, 0.6 of it the blur; one core, 2026-12-05).
"""

from __future__ import annotations

import math

import numpy as np
from depotbench.core.jit import jit

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
    pixel would still be a corner, less 1 (OpenCV's, which ORB ranks by). The threshold is
    clamped to 0-255, so that one above 255 finds nothing (OpenCV's detector takes it modulo
    256; the tracker's settings keep it within 1-100, where the two agree)."""
    rows, cols = image.shape
    score = np.zeros((rows, cols), np.int16)
    x0, x1 = max(3, border - 1), min(cols - 3, cols - border + 1)  # scored: one more on each side
    y0, y1 = max(3, border - 1), min(rows - 3, rows - border + 1)
    left, right = x0 - 3, x1 + 3
    byte = np.uint8(min(max(threshold, 0), 255))
    for y in range(y0, y1):
        _row_scores(
            image[y - 3, left:right], image[y - 2, left:right], image[y - 1, left:right],
            image[y, left:right], image[y + 1, left:right], image[y + 2, left:right],
            image[y + 3, left:right], byte, score[y, x0:x1],
        )  # fmt: skip
    most = ((rows + 1) // 2) * ((cols + 1) // 2)  # a strict 3 x 3 maximum has no maximum beside it
    xs = np.empty(most, np.int64)
    ys = np.empty(most, np.int64)
    scores = np.empty(most, np.int32)
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
    return xs[:found].copy(), ys[:found].copy(), scores[:found].copy()


@jit
def _row_scores(r0, r1, r2, r3, r4, r5, r6, threshold, out):
    """One row's FAST scores, branch-free in bytes so that it runs 32 pixels a vector (a
    tenth of the cost of testing each pixel and then scoring the ~16 % that pass at threshold
    7). A pixel's score is the best of its two arcs: over the 16 arcs of 9 circle pixels, the
    largest of the smallest difference to the centre, darker or brighter, saturated at 0;
    it is a corner where that exceeds ``threshold``. Row r3 holds the pixels with 3 more
    columns on each side (pixel i sits at r3[i + 3]); r0..r6 are the rows 3 above to 3
    below; p0..p15 are FAST's circle (Bresenham, radius 3) clockwise from the top."""
    for i in range(len(out)):
        v = r3[i + 3]
        p0, p1, p2, p3 = r0[i + 3], r0[i + 4], r1[i + 5], r2[i + 6]
        p4, p5, p6, p7 = r3[i + 6], r4[i + 6], r5[i + 5], r6[i + 4]
        p8, p9, p10, p11 = r6[i + 3], r6[i + 2], r5[i + 1], r4[i]
        p12, p13, p14, p15 = r3[i], r2[i], r1[i + 1], r0[i + 2]
        darker = _best_arc(
            _less(v, p0), _less(v, p1), _less(v, p2), _less(v, p3),
            _less(v, p4), _less(v, p5), _less(v, p6), _less(v, p7),
            _less(v, p8), _less(v, p9), _less(v, p10), _less(v, p11),
            _less(v, p12), _less(v, p13), _less(v, p14), _less(v, p15),
        )  # fmt: skip
        brighter = _best_arc(
            _less(p0, v), _less(p1, v), _less(p2, v), _less(p3, v),
            _less(p4, v), _less(p5, v), _less(p6, v), _less(p7, v),
            _less(p8, v), _less(p9, v), _less(p10, v), _less(p11, v),
            _less(p12, v), _less(p13, v), _less(p14, v), _less(p15, v),
        )  # fmt: skip
        best = max(darker, brighter)
        out[i] = np.int16(best) - np.int16(1) if best > threshold else np.int16(0)


@jit
def _less(a, b):
    """a - b saturated at 0, as a byte (written so that it stays one: a vector instruction)."""
    return np.uint8(max(a, b) - b)


@jit
def _best_arc(d0, d1, d2, d3, d4, d5, d6, d7, d8, d9, d10, d11, d12, d13, d14, d15):
    """The largest minimum over 9 circle values in a row: minima of pairs, then of fours,
    then eights and one more."""
    c0, c1, c2, c3 = min(d0, d1), min(d1, d2), min(d2, d3), min(d3, d4)
    c4, c5, c6, c7 = min(d4, d5), min(d5, d6), min(d6, d7), min(d7, d8)
    c8, c9, c10, c11 = min(d8, d9), min(d9, d10), min(d10, d11), min(d11, d12)
    c12, c13, c14, c15 = min(d12, d13), min(d13, d14), min(d14, d15), min(d15, d0)
    e0, e1, e2, e3 = min(c0, c2), min(c1, c3), min(c2, c4), min(c3, c5)
    e4, e5, e6, e7 = min(c4, c6), min(c5, c7), min(c6, c8), min(c7, c9)
    e8, e9, e10, e11 = min(c8, c10), min(c9, c11), min(c10, c12), min(c11, c13)
    e12, e13, e14, e15 = min(c12, c14), min(c13, c15), min(c14, c0), min(c15, c1)
    first = max(min(e0, e4, d8), min(e1, e5, d9), min(e2, e6, d10), min(e3, e7, d11))
    second = max(min(e4, e8, d12), min(e5, e9, d13), min(e6, e10, d14), min(e7, e11, d15))
    third = max(min(e8, e12, d0), min(e9, e13, d1), min(e10, e14, d2), min(e11, e15, d3))
    fourth = max(min(e12, e0, d4), min(e13, e1, d5), min(e14, e2, d6), min(e15, e3, d7))
    return max(first, second, third, fourth)


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


@jit
def describe(pixels, starts, widths, xs, ys, levels, angles, pattern):
    """ORB's 256-bit descriptor of each keypoint (OpenCV's ``ORB.compute``, bit for bit): the
    ``pattern``'s point pairs (x0, y0, x1, y1 per bit) rotated by the keypoint's angle, each
    point rounded to a pixel of its level's blurred image, and bit k set where the first is
    darker. ``pixels`` holds every level's blurred image, row by row, level L from
    ``starts[L]`` with ``widths[L]`` columns; (xs, ys) are positions in the keypoint's level.
    The rotation is OpenCV's float arithmetic: the angle in radians as a float32 product, its
    cosine and sine in double precision rounded to float32 (a float32 cosine rounds one of
    two million angles apart and moves a sample), each coordinate two float32 products and a
    sum, rounded half to even."""
    n = len(xs)
    out = np.zeros((n, 32), np.uint8)
    to_radians = np.float32(math.pi / 180.0)
    for k in range(n):
        angle = np.float32(angles[k]) * to_radians
        a, b = np.float32(math.cos(np.float64(angle))), np.float32(math.sin(np.float64(angle)))
        width = widths[levels[k]]
        centre = starts[levels[k]] + ys[k] * width + xs[k]
        for byte in range(32):
            value = 0
            for bit in range(8):
                pair = 8 * byte + bit
                u, v = np.float32(pattern[pair, 0]), np.float32(pattern[pair, 1])
                first = pixels[
                    centre + np.int64(np.rint(u * b + v * a)) * width + np.int64(np.rint(u * a - v * b))
                ]
                u, v = np.float32(pattern[pair, 2]), np.float32(pattern[pair, 3])
                second = pixels[
                    centre + np.int64(np.rint(u * b + v * a)) * width + np.int64(np.rint(u * a - v * b))
                ]
                if first < second:
                    value |= 1 << bit
            out[k, byte] = value
    return out
