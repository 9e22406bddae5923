"""Sequences and outputs packed to cross between a cluster's driver and its nodes.

On a cluster with no shared file system (``eval/run/nodes.py`` says how jobs use this),
what one machine wrote must travel as bytes: ``pack`` makes a sequence an uncompressed tar
(its PNGs are compressed already) of the files ``Sequence.files`` names and its marker,
under the folder's own name (a real TUM folder's camera is guessed from its name);
``unpack`` makes it a folder again, whole or not at all. A suite's sequence is rendered on
a node (``render_on_node``), kept in the node's sequence store, and sent back for the
driver to write (``unpack_output``), so only the driver writes the suite folder.
"""

from __future__ import annotations

import io
import os
import shutil
import socket
import tarfile
import tempfile
from pathlib import Path
from typing import Any

from depotbench.core.errors import InputError
from depotbench.core.output import MARKER_NAME, OutputKind


def pack(root: Path) -> bytes:
    """The sequence at ``root`` as an uncompressed tar (its PNGs are compressed already):
    the files ``Sequence.files`` names and the marker, under ``root``'s name."""
    from depotbench.sim.sequence import Sequence

    sequence = Sequence.open(root)
    names = [p.relative_to(sequence.root) for p in sequence.files()]
    if (sequence.root / MARKER_NAME).is_file():
        names.append(Path(MARKER_NAME))
    return _tar(sequence.root, root.name, names)


def pack_folder(folder: Path) -> bytes:
    """Every regular file under ``folder`` (a run's output), as ``pack`` packs a sequence."""
    files = sorted(p for p in folder.rglob("*") if p.is_file() and not p.is_symlink())
    return _tar(folder, folder.name, [p.relative_to(folder) for p in files])


def _tar(root: Path, top: str, names: list[Path]) -> bytes:
    """The files ``names`` (relative to ``root``) as an uncompressed tar, under ``top/``."""
    buffer = io.BytesIO()
    with tarfile.open(fileobj=buffer, mode="w") as tar:
        for name in names:
            tar.add(root / name, arcname=f"{top}/{name}", recursive=False)
    return buffer.getvalue()


def unpack(data: bytes, folder: Path) -> Path:
    """Unpack ``pack``'s bytes into ``folder`` (made here, whole or not at all: staged beside
    it and renamed); returns the sequence's folder inside it. Tar's ``data`` filter refuses
    links, devices and paths leaving the folder."""
    folder.parent.mkdir(parents=True, exist_ok=True)
    staging = Path(tempfile.mkdtemp(prefix=f".{folder.name}.partial-", dir=folder.parent))
    try:
        with tarfile.open(fileobj=io.BytesIO(data), mode="r") as tar:
            tar.extractall(staging, filter="data")
        names = [p for p in staging.iterdir()]
        if len(names) != 1 or not names[0].is_dir():
            raise InputError(f"{folder}: a shipped sequence holds {len(names)} top folders, not 1")
        try:
            staging.rename(folder)
        except OSError:  # another worker of this node made it meanwhile: keep that one
            if not folder.is_dir():
                raise
        return folder / names[0].name
    finally:
        shutil.rmtree(staging, ignore_errors=True)


def node_root() -> Path:
    """Where this node keeps what it makes: its cache root (``DEPOTBENCH_CACHE`` as the node's
    own environment sets it), or a folder of the system's temporary space when it is off."""
    from depotbench.core.cache_home import cache_root

    root = cache_root()
    return root if root is not None else Path(tempfile.gettempdir()) / f"depotbench-node-{os.getuid()}"


def node_name() -> str:
    """This node, as a line names it: its host and, on Ray, its node's id (several nodes may
    share a host)."""
    try:
        import ray

        node = ray.get_runtime_context().get_node_id()[:8] if ray.is_initialized() else None
    except ImportError:
        node = None
    return f"{socket.gethostname()} ({node})" if node else socket.gethostname()


def render_on_node(scenario_data: dict[str, Any], name: str, png_compression: int) -> bytes:
    """Worker entry point of suite generation on a cluster: render the sequence on this node
    (or copy it from the node's store), keep it in the store for the jobs that will track it
    here, and return it packed for the driver, which alone writes the suite folder."""
    from depotbench.scenes.schema import Scenario, to_scenario
    from depotbench.scenes.store import SequenceStore
    from depotbench.sim.generate import generate
    from depotbench.sim.spec import content_key

    spec = to_scenario(Scenario.model_validate(scenario_data))
    key = content_key(spec)
    store = SequenceStore.from_env()
    with tempfile.TemporaryDirectory(prefix="depotbench-render-", dir=node_root_made()) as work:
        target = Path(work) / name
        if store is None or not store.fetch(key, target, png_compression):
            generate(spec, target, progress=False, png_compression=png_compression)
            if store is not None:
                store.put(target, key, png_compression)
        return pack(target)


def node_root_made() -> Path:
    root = node_root()
    root.mkdir(parents=True, exist_ok=True)
    return root


def unpack_output(data: bytes, target: Path, kind: OutputKind, key: str | None = None) -> None:
    """The driver's side of ``render_on_node`` (a sequence) or of a run on a node: write the
    packed folder at ``target`` as this machine writes one (staged, locked, swapped into place
    with the marker of ``kind`` and ``key``)."""
    from depotbench.core.output import StagedOutput

    with StagedOutput(target, kind, overwrite=True, content_key=key) as out:
        with tarfile.open(fileobj=io.BytesIO(data), mode="r") as tar:
            top = {Path(m.name).parts[0] for m in tar.getmembers()}
            if len(top) != 1:
                raise InputError(f"{target}: a packed output came back with {len(top)} top folders")
            (prefix,) = top
            for member in tar.getmembers():
                relative = Path(member.name).relative_to(prefix)
                if relative == Path(MARKER_NAME) or not member.isfile():
                    continue  # the marker is StagedOutput's to write
                member.name = str(relative)
                tar.extract(member, out.path, filter="data")
        out.commit()
