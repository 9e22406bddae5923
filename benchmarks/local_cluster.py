"""A Ray cluster of several nodes on one machine, sharing no folder: for the cluster test and
benchmark (``tests/test_cluster.py``, ``benchmarks/cluster.py``), and for a user trying a
cluster before renting one.

Usage: python benchmarks/local_cluster.py [--workers 2] [--cpus 1] [--hide FOLDER ...] [-o FOLDER]
(prints the address and the token the driver needs, then holds the cluster until Ctrl-C)

The head runs no job (``--num-cpus 0``). Each worker node is a ``ray start`` of its own in a
mount namespace of its own (``unshare -m``, so root, or a user namespace) where the folders
it must not read (the driver's, the other nodes') are covered by an empty tmpfs: a job
that opens a path valid only on the driver finds nothing there. Each node's
``DEPOTBENCH_CACHE`` is a folder of its own.
"""

from __future__ import annotations

import contextlib
import os
import secrets
import shlex
import shutil
import signal
import socket
import subprocess
import sys
import tempfile
import time
from dataclasses import dataclass, field
from pathlib import Path

START_TIMEOUT_S = 120.0
OBJECT_STORE_BYTES = 512 << 20
"""Per node: a sweep's sequences in flight, not the machine's 30 % default (7 GB here)."""


def free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def can_hide_folders() -> str | None:
    """None when this machine can start nodes with private mount namespaces; else why not."""
    if shutil.which("unshare") is None:
        return "no unshare(1)"
    probe = subprocess.run(["unshare", "-m", "--propagation", "private", "true"], capture_output=True)
    return None if probe.returncode == 0 else f"unshare -m fails: {probe.stderr.decode().strip()}"


@dataclass
class LocalCluster:
    """``with LocalCluster(base, workers=2, hide=[driver_folder]) as cluster:`` then
    ``--backend ray --address cluster.address``."""

    base: Path
    workers: int = 2
    hide: list[Path] = field(default_factory=list)
    cpus_per_node: int = 1
    address: str = ""
    driver_env: dict[str, str] = field(default_factory=dict)
    nodes: list[subprocess.Popen] = field(default_factory=list)
    head: subprocess.Popen | None = None

    def node_folder(self, i: int) -> Path:
        return self.base / f"node{i}"

    def __enter__(self) -> LocalCluster:
        ray = str(Path(sys.executable).with_name("ray"))
        port = free_port()
        self.address = f"127.0.0.1:{port}"
        # Ray 2.59 and later ask local clusters for a token: one of its own, which the driver
        # takes from ``driver_env``.
        self.driver_env = {"RAY_AUTH_MODE": "token", "RAY_AUTH_TOKEN": secrets.token_hex(32)}
        env = os.environ | {"RAY_USAGE_STATS_ENABLED": "0"} | self.driver_env
        common = [
            "--block",
            "--disable-usage-stats",
            "--node-ip-address=127.0.0.1",
            f"--object-store-memory={OBJECT_STORE_BYTES}",
        ]
        self.head = subprocess.Popen(
            [ray, "start", "--head", f"--port={port}", "--num-cpus=0", "--include-dashboard=false", *common],
            env=env,
            start_new_session=True,
            stdout=subprocess.DEVNULL,
            stderr=subprocess.DEVNULL,
        )
        self._wait_for(0)
        folders = [self.node_folder(i) for i in range(self.workers)]
        for own in folders:
            (own / "cache").mkdir(parents=True, exist_ok=True)
            hidden = [*self.hide, *(f for f in folders if f != own)]
            mounts = " && ".join(f"mount -t tmpfs none {shlex.quote(str(p))}" for p in hidden if p.is_dir())
            # Nodes of one machine would race for the same default ports (the agent's 52365):
            # each gets free ones, and starts after the one before it is up.
            ports = [
                f"--{name}-port={free_port()}"
                for name in (
                    "dashboard-agent-listen",
                    "dashboard-agent-grpc",
                    "metrics-export",
                    "runtime-env-agent",
                )
            ]
            start = shlex.join(
                [
                    ray,
                    "start",
                    f"--address={self.address}",
                    f"--num-cpus={self.cpus_per_node}",
                    *common,
                    *ports,
                ]
            )
            script = f"{mounts} && exec {start}" if mounts else f"exec {start}"
            node_env = env | {"DEPOTBENCH_CACHE": str(own / "cache")}
            node_env.pop("DEPOTBENCH_CACHE_SEQUENCES", None)  # each node's own store, on
            self.nodes.append(
                subprocess.Popen(
                    ["unshare", "-m", "--propagation", "private", "sh", "-c", script],
                    env=node_env,
                    start_new_session=True,
                    stdout=subprocess.DEVNULL,
                    stderr=(self.base / f"{own.name}.log").open("w"),  # why a node did not start
                )
            )
            self._wait_for(len(self.nodes))
        return self

    def _wait_for(self, workers: int) -> None:
        """Until the head answers and ``workers`` worker nodes (CPUs) are alive."""
        deadline = time.monotonic() + START_TIMEOUT_S
        probe = (
            "import ray, sys; ray.init(address=sys.argv[1], logging_level='ERROR'); "
            "print(int(ray.cluster_resources().get('CPU', 0)))"
        )
        while time.monotonic() < deadline:
            done = subprocess.run(
                [sys.executable, "-c", probe, self.address],
                capture_output=True,
                text=True,
                timeout=60,
                env=os.environ | self.driver_env,
            )
            if done.returncode == 0 and int(done.stdout.strip() or 0) >= workers * self.cpus_per_node:
                return
            time.sleep(1.0)
        self.__exit__(None, None, None)
        logs = sorted(self.base.glob("node*.log"))
        raise RuntimeError(
            f"the local Ray cluster at {self.address} did not start {workers} worker nodes; "
            f"their output: {', '.join(map(str, logs)) or 'none'}"
        )

    def kill_node(self, i: int) -> None:
        """SIGKILL worker node ``i`` whole (its raylet, object store and workers)."""
        os.killpg(self.nodes[i].pid, signal.SIGKILL)
        self.nodes[i].wait()

    def __exit__(self, *exc: object) -> None:
        self._stop()
        # The head names itself in /tmp/ray/ray_current_cluster; left behind, a later
        # ray.init() on this machine took it for a live cluster and refused num_cpus.
        current = Path(tempfile.gettempdir()) / "ray" / "ray_current_cluster"
        port = self.address.rpartition(":")[2]
        with contextlib.suppress(OSError):
            if port and current.read_text().strip().endswith(f":{port}"):
                current.unlink()

    def _stop(self) -> None:
        for process in [*self.nodes, self.head]:
            if process is not None and process.poll() is None:
                os.killpg(process.pid, signal.SIGTERM)
        for process in [*self.nodes, self.head]:
            if process is None:
                continue
            try:
                process.wait(20)
            except subprocess.TimeoutExpired:
                os.killpg(process.pid, signal.SIGKILL)
                process.wait()


def main() -> None:
    import argparse

    parser = argparse.ArgumentParser(
        description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    parser.add_argument("--workers", type=int, default=2, help="worker nodes")
    parser.add_argument("--cpus", type=int, default=1, help="CPUs (jobs at a time) per worker node")
    parser.add_argument(
        "--hide", type=Path, nargs="*", default=[], help="folders the worker nodes must not see"
    )
    parser.add_argument("-o", type=Path, default=None, help="the nodes' folders (default: a temporary one)")
    args = parser.parse_args()

    base = args.o or Path(tempfile.mkdtemp(prefix="depotbench-nodes-"))
    with LocalCluster(base, workers=args.workers, hide=args.hide, cpus_per_node=args.cpus) as cluster:
        exports = " ".join(f"{k}={v}" for k, v in cluster.driver_env.items())
        print(f"{exports} depotbench sweep SPEC -o OUT --backend ray --address {cluster.address}", flush=True)
        with contextlib.suppress(KeyboardInterrupt):  # Ctrl-C: the nodes are stopped on the way out
            signal.pause()


if __name__ == "__main__":
    main()
