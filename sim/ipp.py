"""OpenCV without Intel IPP where the generator's bytes come from it.

OpenCV hands some calls (a cubic or area resize, a remap) to Intel IPP, which picks its
code by CPU (``OPENCV_IPP`` shows the choice: sse42, avx2, avx512) and rounds
differently on each: the textures drawn with IPP's SSE 4.2 code differed from its AVX2
code's in a texel now and then (a wood texture of seed 1: one texel, one level).
OpenCV's own code gave the same bits with AVX2, with AVX and AVX2 turned off
(``OPENCV_CPU_DISABLE``) and with IPP's SSE 4.2 path, so the generator calls it
instead; tests/test_sim.py compares textures and the sensor model on two IPP paths.
"""

from __future__ import annotations

from collections.abc import Iterator
from contextlib import contextmanager

import cv2


@contextmanager
def without_ipp() -> Iterator[None]:
    """OpenCV's own code for the calls inside (the setting is the calling thread's)."""
    was = cv2.ipp.useIPP()
    cv2.ipp.setUseIPP(False)
    try:
        yield
    finally:
        cv2.ipp.setUseIPP(was)
