"""A stand-in for a user's program whose time per frame is known, for the tests of typed
parameters and of time budgets (docs/external-trackers.md).

It "tracks" by copying the sequence's true trajectory, and per frame it sleeps
``sleep_ms`` (wall time, no CPU) and then spins ``spin_ms`` (CPU time). Where it is given
``{times}`` and its ``report_ms`` parameter is set, it writes that time for every frame
there. It appends what it was given (its parameters as JSON and its ``TIMED_*``
environment) as one JSON line to the file ``$TIMED_RECORD`` names, where set.

    timed_slam.py SEQUENCE PARAMETERS TRAJECTORY [TIMES]
"""

import json
import os
import sys
import time
from pathlib import Path


def main() -> int:
    sequence, parameters, trajectory = map(Path, sys.argv[1:4])
    times = Path(sys.argv[4]) if len(sys.argv) > 4 else None
    params = json.loads(parameters.read_text())
    record = os.environ.get("TIMED_RECORD")
    if record:
        given = {"params": params, "env": {k: v for k, v in os.environ.items() if k.startswith("TIMED_")}}
        with open(record, "a") as handle:
            handle.write(json.dumps(given, sort_keys=True) + "\n")
    sleep_s, spin_s = params.get("sleep_ms", 0) / 1000.0, params.get("spin_ms", 0) / 1000.0
    stamps, lines = [], []
    for line in (sequence / "groundtruth.txt").read_text().splitlines():
        if line.startswith("#") or not line.strip():
            continue
        time.sleep(sleep_s)
        until = time.process_time() + spin_s
        while time.process_time() < until:
            pass
        stamps.append(line.split()[0])
        lines.append(line + "\n")
    trajectory.write_text("# timed\n" + "".join(lines))
    report = params.get("report_ms")
    if times is not None and report:
        body = "".join(f"{stamp} {report}\n" for stamp in stamps)
        times.write_text("# depotbench times 1\n# timestamp ms\n" + body)
    return 0


if __name__ == "__main__":
    sys.exit(main())
