"""Compiled hot paths of tracking and mapping, and the one switch between them and NumPy.

Pose refinement, the searches by projection, the Schur-complement local bundle adjustment, the
map points' distinctive descriptors and method 3's epipolar and flow tests run on a few hundred
to a few thousand points per call, several times per frame: in NumPy each call pays ~10 us per
array operation whatever the size (pose refinement, 40 Gauss-Newton steps of ~15 operations,
cost 2.6 ms of a 15 ms frame on walking_xyz). Compiled with Numba each is one loop over the
points.

The NumPy functions stay the reference: each compiled kernel (``kernels.optimize`` for pose
refinement and local BA, ``kernels.matching``, ``kernels.rejection``) takes and returns what its
reference does, and ``tests/test_kernels.py`` holds each to it within a stated tolerance.
``DEPOTBENCH_KERNELS`` (``core.jit``, shared with the generator's kernels) picks the path:
numba (the default where numba imports) or the NumPy reference throughout.

Kernels compile with ``cache=True`` (Numba's cache beside the module, else under
``~/.cache/numba`` or ``NUMBA_CACHE_DIR``), so only the first process compiles (40-50 s for all
of them on a 2-core machine, 2026-12-03); every later one pays 0.3 s to import numba and 0.5 s to
load them, once, which 150 frames repay. Where no cache folder is writable they compile in
memory in each process (``core.jit``). No kernel uses threads or ``fastmath``: the sweep
runs one process per core, and the results must match NumPy's arithmetic, not reassociate it.
"""

from __future__ import annotations

import functools
import time

from depotbench.core.jit import LOG, VARIABLE, Kernels, compiled, kernels, using, warmed
from depotbench.core.logs import DETAIL

__all__ = ["VARIABLE", "Kernels", "compiled", "kernels", "ready", "using", "warm_up"]


def warm_up(parts: tuple[str, ...] | None = None) -> float:
    """Compile every kernel now (or load it from Numba's cache), on tiny inputs of the types
    the pipeline passes; returns the seconds it took. A timed run calls it first so that no
    frame pays for it: 0.5 s from the cache, 50 s compiling (2-core machine, 2026-12-03:
    optimize 20 s, features 17, matching 13, rejection 1). ``parts`` names some of
    ``WARM_UPS`` (all by default), so that ``tests/prepare.py`` compiles them in two
    processes side by side."""
    started = time.perf_counter()
    for part in WARM_UPS if parts is None else parts:
        WARM_UPS[part]()
    return time.perf_counter() - started


N = 4
"""Points in the warm-up inputs."""


def _warm_optimize() -> None:
    import numpy as np
    from depotbench.slam.kernels import optimize

    points = np.c_[np.arange(N, dtype=np.float64), np.ones(N), np.full(N, 2.0)]
    uv, ones, index = np.zeros((N, 2)), np.ones(N), np.arange(N, dtype=np.int64)
    optimize.solve(np.eye(2), np.ones(2))
    optimize.refine_pose(np.eye(4), points, uv, ones, ones, 1.0, 1.0, 0.0, 0.0, 1.0, 1, 1, 7.8, 6.0, 1e-6)
    poses, slot = np.eye(4)[None].repeat(2, axis=0), np.zeros(N, np.int64)
    measured, stereo = np.zeros((N, 3)), np.ones(N, np.bool_)
    camera = (1.0, 1.0, 0.0, 0.0, 1.0, 2.8, 1e-6)
    index_zero = np.zeros(N, np.int64)
    optimize.cost(poses, points, index_zero, index, measured, stereo, ones, *camera)
    linear = optimize.linearise(poses, points, index_zero, index, slot, measured, stereo, ones, *camera, 1, N)
    grouping = (np.arange(N + 1, dtype=np.int64), index, slot)
    _, _, _, v_inverse = optimize.reduce(*linear, 1e-5, *grouping)
    optimize.back_substitute(np.zeros((1, 6)), linear[3], linear[4], v_inverse, *grouping)
    optimize.camera_points(poses, points, index_zero, index)


def _warm_matching() -> None:
    import numpy as np
    from depotbench.slam.kernels import matching

    uv, ones, index = np.zeros((N, 2)), np.ones(N), np.arange(N, dtype=np.int64)
    descriptors = np.zeros((N, 32), np.uint8)
    matching.pair(uv, ones, index, index, uv, index, index, descriptors, descriptors, 100, *(ones,) * 4)
    matching.pair_local(uv, ones, index, ones, uv, index, index, descriptors, descriptors, 100, ones)
    matching.pair_fuse(uv, ones, index, ones, uv, index, index, ones, ones, *(descriptors,) * 2, 7.8, 6.0, 50)
    bools = np.zeros(N, np.bool_)
    epipolar = (np.eye(3), uv, uv, ones, bools, bools, bools, descriptors, descriptors)
    matching.pair_triangulation(*epipolar, 3.84, 50)
    matching.distinctive(descriptors, index, np.ones(N, np.int64))
    matching.hamming_matrix(descriptors, descriptors)


def _warm_rejection() -> None:
    import numpy as np
    from depotbench.slam.kernels import rejection

    uv, ones = np.zeros((N, 2)), np.ones(N)
    rejection.epipolar_geometry(np.eye(3), uv, uv)
    rejection.flow_outliers(ones, 2.0, 1.0, 1.0)


def _warm_features() -> None:
    import numpy as np
    from depotbench.slam.kernels import features

    ones, index = np.ones(N), np.arange(N, dtype=np.int64)
    features.distribute(ones, ones, ones, 4, 4, 2)
    image = np.zeros((40, 40), np.uint8)
    features.fast_corners(image, 7, 19)
    features.moments(image, index + 18, index + 18, np.ones(2, np.int64))
    starts, widths = np.zeros(1, np.int64), np.full(1, 40, np.int64)
    pattern = np.zeros((256, 4), np.int64)
    features.describe(
        image.ravel(), starts, widths, index + 18, index + 18, index * 0, ones.astype(np.float32), pattern
    )


WARM_UPS = {
    "optimize": _warm_optimize,
    "matching": _warm_matching,
    "rejection": _warm_rejection,
    "features": _warm_features,
}
"""Each kernel module's warm-up, by name."""


def ready() -> float:
    """Compile (or load) every kernel once in this process, before anything is timed; returns
    the seconds it took (0.0 on the NumPy path). Every process that tracks calls it before its
    first timed frame or stage (``BuiltinTracker``, the stage cache), so no stored timing
    includes compilation; the seconds are kept apart (a run's ``kernels_s``). A warm-up longer
    than ``ANNOUNCE_AFTER_S`` is announced, so the wait reads as a step of its own."""
    return _ready(kernels())


@functools.cache
def _ready(path: Kernels) -> float:
    """``ready`` once per path (``using`` switches it within a process)."""
    if path is not Kernels.NUMBA:
        LOG.log(DETAIL, "kernels: the NumPy path (%s=numpy, or no numba), nothing to compile", VARIABLE)
        return 0.0
    # 20.7 and 21.5 s from an empty cache on an AVX-512 EPYC (2026-12-05), 40-50 s on an AVX2 one
    return warmed("kernels", warm_up, compile_s=(20, 50))
