"""Compiled keypoint distribution: ORB-SLAM's DistributeOctTree as one loop
(``depotbench.slam.features.distribute_numpy`` is the reference, equal to it index for index).

The level's candidates are split into a quadtree until it has as many leaves as the level
wants keypoints, and each leaf keeps its strongest corner. The reference walks Python lists of
nodes; here each node is a run of one index array, split in place, stable.
"""

from __future__ import annotations

import math

import numpy as np
from depotbench.slam.kernels.jit import jit

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
