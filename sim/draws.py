"""Seeded picks among named options, drawn as ``Generator.choice`` draws them.

``Generator.choice`` given a list of strings swallows an exception raised inside it
(numpy 2.4: every one of 600 simulated Ctrl-Cs was lost, where a list of floats lost
none), so world building picks an index instead: the same draw from the same stream,
and a Ctrl-C is never lost in it.
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import TypeVar

import numpy as np

T = TypeVar("T")


def pick(rng: np.random.Generator, options: Sequence[T], p: Sequence[float] | None = None) -> T:
    """One of ``options``; the stream advances exactly as ``rng.choice(options, p=p)``."""
    return options[int(rng.choice(len(options), p=p))]


def picks(rng: np.random.Generator, options: Sequence[T], count: int) -> list[T]:
    """``count`` of ``options`` with replacement, as ``rng.choice(options, count)``."""
    return [options[int(i)] for i in rng.choice(len(options), count)]
