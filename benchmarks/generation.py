"""Generation speed: simulate + render + ground truth + write, frames per second.

Usage: python benchmarks/generation.py [--frames N] [--width W --height H]
Prints the rate of one process and of two processes in parallel (spawned workers,
each with its own GL context, as rendering-notes.md requires).
"""

from __future__ import annotations

import argparse
import dataclasses
import multiprocessing as mp
import os
import tempfile
import time
from pathlib import Path


def _run(args: tuple[int, int, int, int, str, int]) -> float:
    frames, width, height, seed, out, gl_threads = args
    if gl_threads:
        os.environ["LP_NUM_THREADS"] = str(gl_threads)  # Mesa llvmpipe reads it at context creation
    from sim.generate import generate
    from sim.spec import default_scenario

    spec = dataclasses.replace(
        default_scenario(frames=frames, seed=seed),
        width=width,
        height=height,
        focal_px=525.0 * width / 640,
    )
    from sim.world import build_world

    build_world(spec)  # warm imports and texture code before timing
    start = time.perf_counter()
    generate(spec, Path(out), progress=False)
    return frames / (time.perf_counter() - start)


def main() -> None:
    parser = argparse.ArgumentParser()
    parser.add_argument("--frames", type=int, default=90)
    parser.add_argument("--width", type=int, default=640)
    parser.add_argument("--height", type=int, default=480)
    args = parser.parse_args()
    ctx = mp.get_context("spawn")
    with tempfile.TemporaryDirectory() as tmp:

        def jobs(first: int, n: int, gl_threads: int) -> list:
            return [
                (args.frames, args.width, args.height, seed, f"{tmp}/s{seed}", gl_threads)
                for seed in range(first, first + n)
            ]

        with ctx.Pool(1) as pool:
            single = pool.map(_run, jobs(0, 1, 0))[0]
        with ctx.Pool(2) as pool:
            start = time.perf_counter()
            rates = pool.map(_run, jobs(1, 2, 0))
            wall = time.perf_counter() - start
        with ctx.Pool(2) as pool:
            start = time.perf_counter()
            rates_1t = pool.map(_run, jobs(3, 2, 1))
            wall_1t = time.perf_counter() - start
    print(f"default scenario, {args.width}x{args.height}, {args.frames} frames, includes PNG writes")
    print(f"1 process : {single:6.1f} frames/s")
    print(
        f"2 processes: {rates[0]:6.1f} + {rates[1]:6.1f} = {sum(rates):6.1f} frames/s "
        f"(x{sum(rates) / single:.2f}; {2 * args.frames / wall:.1f} frames/s over the wall time, "
        "start-up included)"
    )
    print(
        f"2 processes, 1 llvmpipe thread each: {sum(rates_1t):6.1f} frames/s "
        f"(x{sum(rates_1t) / single:.2f}; {2 * args.frames / wall_1t:.1f} over the wall time)"
    )


if __name__ == "__main__":
    main()
