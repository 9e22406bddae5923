"""Jobs on the nodes of a cluster with no shared file system.

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
  ``<cache root>/shipped/<files key>/<name>``. Copying beats rendering again: a frame of
  walking_static (640x480 with its truth files) renders in about 270 ms and packs to
  0.86 MB, 7 ms at 1 Gbit/s, so a copy is 23-26x cheaper and rendering wins only below
  about 27 Mbit/s (measured: ``benchmarks/cluster.py``). A user's own sequences
  (never rendered) can only be copied.
- **Checked.** The node hashes what it made; a files key other than the driver's (another
  generator, a damaged copy) fails the job with one line naming the node and the
  sequence, never a row under the wrong key.
"""

from __future__ import annotations

import logging
import shutil
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from depotbench.core.errors import InputError
from depotbench.core.output import read_marker
from depotbench.scenes.shipping import node_name, node_root, pack, unpack

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


def source_of(root: Path, fingerprint: str, put: Any) -> SequenceSource:
    """The driver's side: ``root``'s source, its packed files put into the object store by
    ``put`` (``ray.put``)."""
    marker = read_marker(root)
    key = marker.content_key if marker is not None else None
    return SequenceSource(fingerprint, root.name, key, put(pack(root)))


class Shipments:
    """The driver's side over one phase of jobs: each sequence packed and put into Ray's
    object store when the first job that needs it is submitted, and let go by the driver
    once the last one is (Ray keeps an object while a submitted job holds it, a job run
    again after its node died included). So the store holds the sequences of the jobs in
    flight, not every sequence of a sweep: tum-dyn-1's 70 would be about 45 GB."""

    def __init__(self, put: Any, files_keys: dict[str, str]) -> None:
        self.put = put
        self.files_keys = files_keys
        """Each sequence's files key, by the folder its jobs name here."""
        self.put_count = 0

    def around(self, items: list, roots_of: Any) -> Any:
        """``(item, {folder: SequenceSource})`` for each of ``items`` in order, made as they
        are taken; ``roots_of(item)``: the folders the item's jobs name."""
        needs = [sorted(roots_of(item)) for item in items]
        last = {root: i for i, roots in enumerate(needs) for root in roots}
        held: dict[str, SequenceSource] = {}
        for i, (item, roots) in enumerate(zip(items, needs, strict=True)):
            for root in roots:
                if root not in held:
                    held[root] = source_of(Path(root), self.files_keys[root], self.put)
                    self.put_count += 1
            yield item, {root: held[root] for root in roots}
            for root in roots:
                if last[root] == i:
                    del held[root]


_LOCAL: dict[str, Path] = {}
"""This worker process's sequences by files key: each is found or made once."""


def local_sequence(source: SequenceSource) -> Path:
    """The node's side: the folder of ``source``'s sequence on this node, made where missing
    (the module's docstring says how) and checked against the driver's files key."""
    known = _LOCAL.get(source.fingerprint)
    if known is not None and known.is_dir():
        return known
    folder = node_root() / SHIPPED / source.fingerprint
    path = folder / source.name
    if not (path.is_dir() and _fingerprint(path) == source.fingerprint):
        shutil.rmtree(folder, ignore_errors=True)  # damaged, or half made by a killed worker
        if not (_from_store(source, path) and _fingerprint(path) == source.fingerprint):
            shutil.rmtree(folder, ignore_errors=True)  # the store's was written at another PNG level
            import ray

            path = unpack(ray.get(source.packed), folder)
            LOG.debug("sequence %s copied from the driver into %s", source.name, path)
            _check(source, path)
    _LOCAL[source.fingerprint] = path
    return path


def _from_store(source: SequenceSource, target: Path) -> bool:
    """Whether this node's sequence store held ``source`` (by content key, at the default PNG
    level) and copied it to ``target``: a copy, since the store may evict an entry while a
    job reads it. The caller checks its files key."""
    if source.content_key is None:
        return False
    from depotbench.scenes.store import SequenceStore

    store = SequenceStore.from_env()
    target.parent.mkdir(parents=True, exist_ok=True)
    if store is None or not store.fetch(source.content_key, target):
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


_PROGRAMS: dict[tuple, str] = {}
"""This node's fingerprint of each tracker it was asked to run."""


def program_differs(tracker: Any, expected: str | None) -> str | None:
    """One line when this node's program (or a file its command names, its settings template
    or vocabulary) is not the bytes the driver keyed the job with (``expected``: the driver's
    ``tracker_fingerprint``): its rows would be another program's under this one's key. The
    built-in's program is this node's depotbench (its ``code_version``): a node with another
    release, or a checkout's driver beside nodes that installed a release, is refused."""
    from depotbench.core.version import code_version
    from depotbench.eval.run.harness import tracker_fingerprint, tracker_identity

    if expected is None:
        return None
    memo = (tracker.label, tracker.command, str(tracker.vocabulary), tracker.settings_template, expected)
    if memo not in _PROGRAMS:
        try:
            _PROGRAMS[memo] = tracker_fingerprint(tracker_identity(tracker))
        except InputError as exc:  # the program or a file it names is missing here
            return f"node {node_name()}: {exc}"
    found = _PROGRAMS[memo]
    if found == expected:
        return None
    if not tracker.type.external:
        return (
            f"node {node_name()}: its depotbench ({code_version()}) is not the driver's "
            f"(built-in fingerprint {found}, the driver's {expected}): install the driver's "
            "depotbench on every node (a driver run from a source checkout needs that checkout there)"
        )
    return (
        f"node {node_name()}: tracker {tracker.label}'s program or the files its command names "
        f"differ from the driver's (fingerprint {found}, the driver's {expected}): install the "
        "same program on every node"
    )
