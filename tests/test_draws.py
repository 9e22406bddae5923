"""Seeded picks: the draws of Generator.choice, without losing a Ctrl-C in it."""

from __future__ import annotations

import _thread
import gc
import signal
import threading
import time

import numpy as np
import pytest
from depotbench.sim import draws
from depotbench.sim.draws import pick, picks

OPTIONS = ("cardboard", "crate", "sack")


@pytest.mark.parametrize("seed", range(20))
def test_picks_draw_what_choice_draws_and_advance_the_stream_alike(seed: int):
    a, b = np.random.default_rng(seed), np.random.default_rng(seed)
    for _ in range(50):
        assert pick(a, OPTIONS, p=(0.5, 0.3, 0.2)) == b.choice(list(OPTIONS), p=[0.5, 0.3, 0.2])
        assert pick(a, OPTIONS) == b.choice(list(OPTIONS))
        assert picks(a, "ABCDEF", 4) == list(b.choice(list("ABCDEF"), 4))
    assert a.random() == b.random()


def _inside_a_pick(frame) -> bool:
    """Whether the interrupted code runs inside ``depotbench.sim.draws`` (a pick, or NumPy
    called from one)."""
    while frame is not None:
        if frame.f_code.co_filename == draws.__file__:
            return True
        frame = frame.f_back
    return False


def _interrupts_caught(draw) -> tuple[int, int]:
    """(Ctrl-Cs raised inside a pick, Ctrl-Cs that reached the caller) while ``draw`` runs in a
    loop under a storm of SIGINTs.

    Only a SIGINT that lands inside a pick raises: the rest of the storm lands anywhere (in
    ``Thread.start``, between the loop's statements, in the clean-up) and would escape the
    test into pytest, where an interrupted clean-up left the storm running and crashed the
    xdist worker (fresh-clone runs under load, before and after collecting garbage first)."""
    raised = caught = 0

    def handler(signum, frame):
        nonlocal raised
        if _inside_a_pick(frame):
            raised += 1
            raise KeyboardInterrupt

    stop = threading.Event()

    def poke():
        while not stop.is_set():
            time.sleep(0.002)
            _thread.interrupt_main()

    poker = threading.Thread(target=poke, daemon=True)
    # Earlier tests' garbage is collected now, not during the storm: a finalizer running inside
    # a pick and interrupted there would be an "unraisable" exception.
    gc.collect()
    gc.disable()
    previous = signal.signal(signal.SIGINT, handler)
    try:
        poker.start()
        started = time.perf_counter()
        while time.perf_counter() - started < 0.3:
            try:
                for _ in range(200):
                    draw()
            except KeyboardInterrupt:
                caught += 1
    finally:
        stop.set()
        poker.join()
        signal.signal(signal.SIGINT, previous)
        gc.enable()
    return raised, caught


def test_a_ctrl_c_during_a_pick_reaches_the_caller():
    """World building drew clothing and crate kinds with rng.choice(list of strings), which
    swallows an exception raised inside it: a Ctrl-C there was lost and generation ran on."""
    rng = np.random.default_rng(0)
    raised, caught = _interrupts_caught(lambda: pick(rng, OPTIONS, p=(0.5, 0.3, 0.2)))
    assert raised > 10 and caught == raised
