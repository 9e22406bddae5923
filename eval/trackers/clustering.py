"""The vocabulary builder's hot loops compiled: Hamming distances to cluster centres and the
bitwise-majority centres of k-majority clustering.

The default vocabulary clusters ~900,000 descriptors into ~10,700 nodes; most nodes hold a few
hundred descriptors, where NumPy's per-call cost (a dozen array operations per centre and per
cluster) was the whole of the 27 s. ``vocabulary.kmajority`` calls these where the compiled
kernels run (``depotbench.slam.kernels``' switch) and its NumPy functions otherwise; both give
the same integers, so the same vocabulary.
"""

from __future__ import annotations

import numpy as np
from depotbench.core.jit import jit


@jit
def _popcount(x: np.uint64) -> int:
    """Set bits of a 64-bit word (SWAR: exact on every word)."""
    x = x - ((x >> np.uint64(1)) & np.uint64(0x5555555555555555))
    x = (x & np.uint64(0x3333333333333333)) + ((x >> np.uint64(2)) & np.uint64(0x3333333333333333))
    x = (x + (x >> np.uint64(4))) & np.uint64(0x0F0F0F0F0F0F0F0F)
    return int((x * np.uint64(0x0101010101010101)) >> np.uint64(56))


@jit
def distances(descriptors: np.ndarray, centres: np.ndarray) -> np.ndarray:
    """``vocabulary._distances``: Hamming distances (n, k) between packed descriptors (n, 4)
    and centres (k, 4), as int32."""
    out = np.empty((len(descriptors), len(centres)), np.int32)
    for i in range(len(descriptors)):
        for c in range(len(centres)):
            total = 0
            for w in range(descriptors.shape[1]):
                total += _popcount(descriptors[i, w] ^ centres[c, w])
            out[i, c] = total
    return out


@jit
def majority_centres(
    descriptor_bytes: np.ndarray, labels: np.ndarray, k: int
) -> tuple[np.ndarray, np.ndarray]:
    """The bitwise majority (ties set the bit, as DBoW2's meanValue) of each non-empty label's
    descriptors ((n, 32) bytes), in label order: (centres (k', 32) bytes, the labels renumbered
    0..k'-1 in the same order), as ``np.unique`` and ``vocabulary._majority`` give them."""
    n, width = descriptor_bytes.shape
    counts = np.zeros((k, width * 8), np.int64)
    members = np.zeros(k, np.int64)
    for i in range(n):
        label = labels[i]
        members[label] += 1
        for j in range(width):
            byte = descriptor_bytes[i, j]
            for b in range(8):  # most significant bit first, as np.unpackbits
                counts[label, 8 * j + b] += (byte >> (7 - b)) & 1
    renumber = np.full(k, -1, np.int64)
    kept = 0
    for label in range(k):
        if members[label] > 0:
            renumber[label] = kept
            kept += 1
    centres = np.zeros((kept, width), np.uint8)
    for label in range(k):
        slot = renumber[label]
        if slot < 0:
            continue
        for j in range(width):
            value = 0
            for b in range(8):
                if 2 * counts[label, 8 * j + b] >= members[label]:
                    value |= 1 << (7 - b)
            centres[slot, j] = value
    relabelled = np.empty(n, np.int64)
    for i in range(n):
        relabelled[i] = renumber[labels[i]]
    return centres, relabelled
