"""Sequences on the nodes of a cluster with no shared file system.

A job sent to another machine names its sequence by what it holds, not by where the
driver keeps it: ``SequenceSource`` carries the sequence's files key
(``eval.run.detections.sequence_fingerprint``), its content key where it was generated,
and a reference to its packed files in Ray's object store. A node makes the sequence
once into a private folder of its own and every job there reads it from that folder:

- **From the node's own store first.** A generated sequence whose content key the node's
  sequence store (``scenes.store``, under the node's own cache root) holds is copied from
  there: a node that rendered it for the suite takes nothing from the driver.
- **Else copied through Ray.** The driver packs each sequence once (``pack``: the files
  ``Sequence.files`` names, the marker, and nothing else from the folder, under the
  folder's own name, since a real TUM folder's camera is guessed from its name) and puts
  it into the object store; a node that lacks it pulls it once and unpacks it into
  ``<cache root>/shipped/<files key>/<name>``. Copying beats rendering again on any
  sequence: a 30-frame smoke sequence renders in about 3 s and ships in about 0.05 s
  on one machine; a 745-frame TUM analog renders in minutes and is 160-400 MB, seconds
  on a 1 Gbit/s link (measured: ``benchmarks/cluster.py``). A user's own sequences
  (never rendered) can only be copied.
- **Checked.** The node hashes what it made; a files key other than the driver's (another
  generator, a damaged copy) fails the job with one line naming the node and the
  sequence, never a row under the wrong key.
"""

from __future__ import annotations

import io
import logging
import os
import shutil
import socket
import tarfile
import tempfile
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from depotbench.core.errors import InputError
from depotbench.core.output import MARKER_NAME, read_marker

LOG = logging.getLogger(__name__)
SHIPPED = "shipped"
"""The folder of the node's cache root that holds the sequences made on it for jobs (one per
files key; unbounded: removing the folder frees it, and a job makes what it needs again)."""


@dataclass(frozen=True)
class SequenceSource:
    """How a node gets one sequence: see the module's docstring."""

    fingerprint: str
    """The driver's ``sequence_fingerprint``: what the node's copy must hash to."""
    name: str
    """The folder's name (a real TUM folder's camera is guessed from it)."""
    content_key: str | None
    """The marker's key of a generated sequence; None for a user's own folder."""
    packed: Any
    """Ray's ``ObjectRef`` of ``pack(folder)``: fetched only by a node that lacks the sequence."""


def pack(root: Path) -> bytes:
    """The sequence at ``root`` as an uncompressed tar (its PNGs are compressed already):
    the files ``Sequence.files`` names and the marker, under ``root``'s name."""
    from depotbench.sim.sequence import Sequence

    sequence = Sequence.open(root)
    names = [p.relative_to(sequence.root) for p in sequence.files()]
    if (sequence.root / MARKER_NAME).is_file():
        names.append(Path(MARKER_NAME))
    buffer = io.BytesIO()
    with tarfile.open(fileobj=buffer, mode="w") as tar:
        for name in names:
            tar.add(sequence.root / name, arcname=f"{root.name}/{name}", recursive=False)
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


def source_of(root: Path, fingerprint: str, put: Any) -> SequenceSource:
    """The driver's side: ``root``'s source, its packed files put into the object store by
    ``put`` (``ray.put``)."""
    marker = read_marker(root)
    key = marker.content_key if marker is not None else None
    return SequenceSource(fingerprint, root.name, key, put(pack(root)))


_LOCAL: dict[str, Path] = {}
"""This worker process's sequences by files key: each is found or made once."""


def local_sequence(source: SequenceSource) -> Path:
    """The node's side: the folder of ``source``'s sequence on this node, made where missing
    (the module's docstring says how) and checked against the driver's files key."""
    known = _LOCAL.get(source.fingerprint)
    if known is not None and known.is_dir():
        return known
    folder = _node_root() / SHIPPED / source.fingerprint
    path = folder / source.name
    if not (path.is_dir() and _fingerprint(path) == source.fingerprint):
        shutil.rmtree(folder, ignore_errors=True)  # damaged, or half made by a killed worker
        if not _from_store(source, path):
            import ray

            path = unpack(ray.get(source.packed), folder)
            LOG.debug("sequence %s copied from the driver into %s", source.name, path)
        _check(source, path)
    _LOCAL[source.fingerprint] = path
    return path


def _node_root() -> Path:
    """Where this node keeps what it makes: its cache root (``DEPOTBENCH_CACHE`` as the node's
    own environment sets it), or a folder of the system's temporary space when it is off."""
    from depotbench.core.cache_home import cache_root

    root = cache_root()
    return root if root is not None else Path(tempfile.gettempdir()) / f"depotbench-node-{os.getuid()}"


def _from_store(source: SequenceSource, target: Path) -> bool:
    """Whether this node's sequence store held ``source`` (by content key, at the default PNG
    level) and copied it to ``target``: a copy, since the store may evict an entry while a
    job reads it."""
    if source.content_key is None:
        return False
    from depotbench.scenes.store import SequenceStore

    store = SequenceStore.from_env()
    target.parent.mkdir(parents=True, exist_ok=True)
    if store is None or not store.fetch(source.content_key, target):
        return False
    if _fingerprint(target) != source.fingerprint:  # written at another PNG level
        shutil.rmtree(target.parent, ignore_errors=True)
        return False
    LOG.debug("sequence %s taken from this node's store into %s", source.name, target)
    return True


def _fingerprint(root: Path) -> str:
    from depotbench.eval.run.detections import sequence_fingerprint
    from depotbench.sim.sequence import Sequence

    return sequence_fingerprint(Sequence.open(root))


def _check(source: SequenceSource, path: Path) -> None:
    found = _fingerprint(path)
    if found != source.fingerprint:
        raise InputError(
            f"node {node_name()}: sequence {source.name} made here holds other files than "
            f"the driver's (files key {found}, the driver's {source.fingerprint}): the nodes run "
            "another depotbench, or the copy was damaged"
        )


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
    with tempfile.TemporaryDirectory(prefix="depotbench-render-", dir=_node_root_made()) as work:
        target = Path(work) / name
        if store is None or not store.fetch(key, target, png_compression):
            generate(spec, target, progress=False, png_compression=png_compression)
            if store is not None:
                store.put(target, key, png_compression)
        return pack(target)


def _node_root_made() -> Path:
    root = _node_root()
    root.mkdir(parents=True, exist_ok=True)
    return root


def unpack_sequence(data: bytes, target: Path, key: str) -> None:
    """The driver's side of ``render_on_node``: write the packed sequence at ``target`` as a
    rendered one is written (staged, locked, swapped into place with the marker of ``key``)."""
    from depotbench.core.output import OutputKind, StagedOutput

    with StagedOutput(target, OutputKind.SEQUENCE, overwrite=True, content_key=key) as out:
        with tarfile.open(fileobj=io.BytesIO(data), mode="r") as tar:
            top = {Path(m.name).parts[0] for m in tar.getmembers()}
            if len(top) != 1:
                raise InputError(f"{target}: a rendered sequence came back with {len(top)} top folders")
            (prefix,) = top
            for member in tar.getmembers():
                relative = Path(member.name).relative_to(prefix)
                if relative == Path(MARKER_NAME) or not member.isfile():
                    continue  # the marker is StagedOutput's to write
                member.name = str(relative)
                tar.extract(member, out.path, filter="data")
        out.commit()
