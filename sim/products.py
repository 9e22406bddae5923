"""Matrix products that give the same bits on every CPU.

numpy's ``@`` hands float matrices to BLAS, and OpenBLAS picks its kernels by CPU type:
Haswell's and later ones fuse multiply and add, Nehalem's do not, so the same product
differs in its last bits from one machine to another. The generator's poses, meshes and
ground truth are products of small matrices; written through ``@`` they made the same
spec and seed give different ``gt/objects.jsonl`` floats, and now and then a pixel one
level off, on another CPU type. ``product`` sums in one fixed order with numpy's
element-wise multiply and add, which round the same everywhere: its results equal the
non-fused kernels' (Nehalem's) bit for bit. Vector dots and lengths (``np.dot`` and
``np.linalg.norm`` of 2- and 3-vectors) measured the same on both kernels and are left
as they are. tests/test_sim.py generates a scene on both kernels and compares bytes.
"""

from __future__ import annotations

import numpy as np


def product(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """``a @ b`` (same shapes and broadcasting) for a short inner dimension, summed in
    order: ``(a0 b0 + a1 b1) + a2 b2 ...``."""
    a = np.asarray(a, dtype=float)
    b = np.asarray(b, dtype=float)
    k = a.shape[-1]
    if b.shape[0 if b.ndim == 1 else -2] != k:
        raise ValueError(f"product: shapes {a.shape} and {b.shape} do not chain")
    if b.ndim == 1:  # (..., k) @ (k,): long strided columns, fast
        out = a[..., 0] * b[0]
        for i in range(1, k):
            out += a[..., i] * b[i]
        return out
    if a.ndim == 2 and b.ndim == 2 and len(a) > COLUMNS_FROM:  # points (N, k) @ (k, m)
        out = np.empty((len(a), b.shape[1]))
        for j in range(b.shape[1]):
            out[:, j] = product(a, b[:, j])
        return out
    if a.ndim == 1:  # (k,) @ (..., k, m)
        terms = [a[i] * b[..., i, :] for i in range(k)]
    else:  # (..., n, k) @ (..., k, m)
        terms = [a[..., :, i, None] * b[..., None, i, :] for i in range(k)]
    out = terms[0]
    for term in terms[1:]:
        out = out + term
    return out


COLUMNS_FROM = 16
"""Rows of ``a`` from which ``product`` works column by column: broadcasting a long (N, 1)
against (1, m) runs numpy's inner loop over m, 3, and took 30 times as long as BLAS on
200,000 points; one column at a time takes 3.5 times as long."""


def rigid_inverse(pose: np.ndarray) -> np.ndarray:
    """The inverse of a 4x4 rigid transform (rotation and translation), without LAPACK."""
    rotation = pose[:3, :3].T
    out = np.eye(4)
    out[:3, :3] = rotation
    out[:3, 3] = -product(rotation, pose[:3, 3])
    return out
