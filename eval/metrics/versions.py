"""Program versions in a result set: rows of one tracker label made by different builds of
its program (different tracker fingerprints) are never paired or averaged together.

A sweep folder keeps the rows of every build that ran into it (a sweep skips only the keys it
has, and a new build's keys are new), so a folder used as a baseline or compared can hold
two versions of one tracker. ``one_version`` keeps the rows of one version per tracker, or
refuses in one line naming the fingerprints and how to choose one or prune the others.
"""

from __future__ import annotations

from collections import Counter
from collections.abc import Iterable, Sequence
from typing import Any

from depotbench.core.errors import InputError
from depotbench.eval.metrics.record import UNKNOWN_FINGERPRINT

PRUNE_HINT = "or keep one with `depotbench sweep SPEC -o {folder} --prune-stale`"


def version_of(row: Any) -> str:
    """A row's tracker fingerprint (a record or a scored run), ``unknown`` for an older row."""
    return row.get("tracker_fingerprint") or UNKNOWN_FINGERPRINT


def versions(rows: Iterable[Any]) -> dict[str, Counter[str]]:
    """Per tracker label, how many rows each of its fingerprints has."""
    out: dict[str, Counter[str]] = {}
    for row in rows:
        out.setdefault(row.get("tracker"), Counter())[version_of(row)] += 1
    return out


def versions_text(counts: Counter[str]) -> str:
    """``a1b2c3d4e5f6 (12 rows), unknown (3 rows)``: most rows first."""
    return ", ".join(f"{name} ({n} row{'s' if n != 1 else ''})" for name, n in counts.most_common())


def chosen_versions(
    found: dict[str, Counter[str]], chosen: Sequence[str], folder: object, option: str
) -> dict[str, str]:
    """Per tracker label with several versions (``versions``), the one fingerprint in
    ``chosen`` (``option``'s values, which may name those of other folders too) whose rows
    to keep; a label with none or two of them chosen is refused naming its fingerprints."""
    keep: dict[str, str] = {}
    for tracker, counts in sorted(found.items()):
        if len(counts) < 2:
            continue
        picked = [name for name in chosen if name in counts]
        if len(picked) != 1:
            raise InputError(
                f"{folder}: tracker {tracker} has rows of {len(counts)} program versions "
                f"(fingerprints {versions_text(counts)}); choose one with {option} FINGERPRINT, "
                + PRUNE_HINT.format(folder=folder)
            )
        keep[tracker] = picked[0]
    return keep


def one_version(rows: list, chosen: Sequence[str], folder: object, option: str) -> list:
    """The rows with one program version per tracker label (``chosen_versions``)."""
    keep = chosen_versions(versions(rows), chosen, folder, option)
    if not keep:
        return rows
    return [r for r in rows if keep.get(r.get("tracker"), version_of(r)) == version_of(r)]


def check_one_version(rows: Iterable[Any], what: str) -> None:
    """Refuse to aggregate ``what`` over rows of two program versions of one tracker."""
    for tracker, counts in versions(rows).items():
        if len(counts) > 1:
            raise InputError(
                f"{what}: tracker {tracker} has rows of {len(counts)} program versions "
                f"(fingerprints {versions_text(counts)}); they are not averaged together: keep one "
                "with `depotbench sweep SPEC -o DIR --prune-stale`"
            )
