"""The dense maps of one sequence under several strategies, seen from above with their ghosts in
red and their figures under them (method 2's two pictures, with numbers): the README's picture.

    python benchmarks/ghost_pictures.py --scenario walking_xyz --seed 21 --frames 90 \
        --strategies none box_epipolar_flow -o ghosts.png

Prints each map's ghost fraction, ghosts per instance, F-score and ATE.
"""

from __future__ import annotations

import argparse
import tempfile
from pathlib import Path

from depotbench.eval.metrics.map import reference_clouds
from depotbench.eval.report.maps import placed_map, top_views

import depotbench


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--scenario", default="walking_xyz")
    parser.add_argument("--seed", type=int, default=21)
    parser.add_argument("--frames", type=int, default=90)
    parser.add_argument("--detector", default="groundtruth")
    parser.add_argument("--strategies", nargs="+", default=["none", "box_epipolar_flow"])
    parser.add_argument("-o", "--output", type=Path, required=True, help="the picture (PNG)")
    args = parser.parse_args()
    with tempfile.TemporaryDirectory(prefix="depotbench-ghosts-") as scratch:
        root = Path(scratch)
        sequence = depotbench.generate(args.scenario, root / "sequence", seed=args.seed, frames=args.frames)
        reference = reference_clouds(sequence)
        maps = []
        for strategy in args.strategies:
            record = depotbench.run(
                sequence, root / strategy, strategy=strategy, detector=args.detector, dense_map=True
            )
            placed = placed_map(root / strategy, reference, strategy)
            ghosts = ", ".join(f"{who} {n}" for who, n in placed.figures["ghosts"].items() if n) or "none"
            print(
                f"{strategy:18s} ghost fraction {record.ghost_fraction:.3f} ({ghosts}); F-score "
                f"{record.map_f_score:.3f}; ATE {record.ate_rmse_m:.4f} m; {len(placed.points_m)} points"
            )
            maps.append(placed)
        fig = top_views(maps)
        fig.suptitle(f"{args.scenario}, seed {args.seed}, {args.frames} frames, {args.detector} boxes", y=1.0)
        fig.savefig(args.output, dpi=110, bbox_inches="tight")
    print(f"wrote {args.output}")


if __name__ == "__main__":
    main()
