"""What a sweep's page shows of a run it tracked again, kept in the sweep folder
(``views/``) by the run's key, so that the page of a finished sweep is written again without
tracking anything: wherever the folder is copied, and whatever the stage cache holds.

A featured run (a family's best and its ``none`` run) is tracked again for its page: its
trajectory, states, per-frame decisions and map are not in the database. The demo's page
tracks about 1,000 frames that way (37 s of a 50 s second demo). The run's key
(``SweepJob.key``: sequence bytes, tracker and program, detector, strategy, settings,
the package's code, ``code_version``) names everything its view depends on, so a view
stored under it is the view tracking gives, and other code looks under other keys.

An entry is one uncompressed numpy archive read with ``allow_pickle=False``: the arrays,
and the JSON metadata (metrics, the map's title and figures) as bytes. A cache holds no code
to run, whoever wrote it.
"""

from __future__ import annotations

import io
import json
import logging
from pathlib import Path
from typing import Any

import numpy as np
from depotbench.eval.metrics.trajectory import Trajectory
from depotbench.eval.run.cache import StageCache, content_hash

LOG = logging.getLogger(__name__)
STAGE = "report_views"
FORMAT = 1
FOLDER = "views"
"""The sweep folder's subfolder of views (a stage cache of its own: ``views/report_views/``)."""
MAX_BYTES = 1 << 30
"""The views a sweep folder keeps, least recently used out first: the demo's six are 4.7 MB;
twelve families' two runs of TUM-length sequences about 300 MB."""


def of_sweep(folder: Path) -> StageCache:
    """The views kept beside the sweep in ``folder``: one that cannot be written (another
    user's folder) is warned about once and the page is written all the same."""
    return StageCache(
        folder / FOLDER,
        MAX_BYTES,
        unwritable="the page is written without keeping its tracked runs' views: the sweep's folder",
    )


def retain(cache: StageCache, job_keys: set[str]) -> int:
    """Keep the views of the runs ``job_keys`` names (the rows the sweep's database holds)
    and remove the others: the views of rows that ``depotbench sweep --prune-stale`` removed,
    which no page reads again. Returns how many went."""
    return cache.retain(STAGE, {view_key(key) for key in job_keys})


def view_key(job_key: str) -> str:
    return content_hash(STAGE, FORMAT, job_key)


def to_bytes(view: Any) -> bytes:
    """A ``RunView`` (its sequence and folder aside: the page has them) as an archive."""
    arrays: dict[str, np.ndarray] = {
        "timestamps_s": np.asarray(view.timestamps_s, float),
        "states": np.asarray(view.states, dtype=str),
    }
    meta: dict[str, Any] = {"format": FORMAT, "title": view.title, "metrics": view.metrics}
    if view.estimate is not None:
        arrays |= {
            "estimate_t": view.estimate.timestamps_s,
            "estimate_p": view.estimate.positions_m,
            "estimate_q": view.estimate.quats_xyzw,
        }
        meta["estimate_name"] = view.estimate.name
    if view.diagnostics is not None:
        arrays |= {f"diagnostics.{name}": value for name, value in view.diagnostics.items()}
    if view.placed is not None:
        p = view.placed
        arrays |= {"map.points_m": p.points_m, "map.colours": p.colours, "map.kinds": p.kinds}
        meta["map"] = {"title": p.title, "figures": p.figures}
    arrays["meta"] = np.frombuffer(json.dumps(meta).encode("utf-8"), dtype=np.uint8)
    buffer = io.BytesIO()
    np.savez(buffer, **arrays)
    return buffer.getvalue()


def from_bytes(data: bytes) -> dict[str, Any] | None:
    """The fields of the ``RunView`` an archive holds (but its title and sequence, which the
    page gives); None where it is not one this version wrote (tracked again then)."""
    from depotbench.eval.report.maps import PlacedMap

    try:
        with np.load(io.BytesIO(data), allow_pickle=False) as archive:
            arrays = {name: archive[name] for name in archive.files}
        meta = json.loads(arrays.pop("meta").tobytes().decode("utf-8"))
    except (ValueError, KeyError, OSError, UnicodeError) as exc:
        LOG.debug("report view cache: an entry that does not read (%s): tracked again", exc)
        return None
    if meta.get("format") != FORMAT:
        return None
    estimate = None
    if "estimate_t" in arrays:
        estimate = Trajectory.from_quaternions(
            arrays["estimate_t"], arrays["estimate_p"], arrays["estimate_q"], meta["estimate_name"]
        )
    prefix = "diagnostics."
    diagnostics = {k[len(prefix) :]: v for k, v in arrays.items() if k.startswith(prefix)} or None
    placed = None
    if "map" in meta:
        placed = PlacedMap(
            meta["map"]["title"],
            arrays["map.points_m"],
            arrays["map.colours"],
            arrays["map.kinds"],
            meta["map"]["figures"],
        )
    return {
        "metrics": meta["metrics"],
        "timestamps_s": arrays["timestamps_s"],
        "states": tuple(str(s) for s in arrays["states"]),
        "estimate": estimate,
        "diagnostics": diagnostics,
        "placed": placed,
    }


def load(cache: StageCache | None, job_key: str) -> dict[str, Any] | None:
    """The stored view's fields of the run ``job_key``, or None (not stored, or damaged)."""
    if cache is None:
        return None
    data = cache.get(STAGE, view_key(job_key))
    return None if data is None else from_bytes(data)


def store(cache: StageCache | None, job_key: str, view: Any) -> None:
    if cache is not None:
        cache.put(STAGE, view_key(job_key), to_bytes(view))
