"""A report folder written for a user: the page of a run or a sweep, and a Rerun recording.

The folder is staged and swapped into place whole, and the recording renamed into place
after it, so a failure at any point (a full disk) leaves neither half-written; bad input
writes nothing. Only a folder of depotbench reports (or a new or empty one) is replaced.
"""

from __future__ import annotations

import contextlib
from dataclasses import dataclass
from pathlib import Path

from depotbench.core.errors import InputError
from depotbench.core.output import OutputKind, StagedOutput, write_text_atomic
from depotbench.eval.report.html import Notes, render_report


@dataclass(frozen=True)
class Written:
    """What ``report_folder`` wrote, and what the page leaves out."""

    page: Path
    recording: Path | None
    notes: Notes


def _check_rerun(source: Path, output: Path, rerun: Path) -> None:
    if not (source / "metrics.json").is_file():
        raise InputError(f"--rerun: {source} is not a run folder (metrics.json)")
    if rerun.exists():
        raise InputError(f"--rerun: {rerun} already exists; remove it or give another name")
    if not rerun.parent.is_dir():
        raise InputError(f"--rerun: {rerun.parent} is not a folder")
    if output.resolve() in rerun.resolve().parents:
        # The report folder is replaced as a whole by the next report: the recording would go.
        raise InputError(f"--rerun: {rerun} lies inside the report folder {output}; give a path outside it")


def report_folder(source: Path, output: Path, rerun: Path | None = None, workers: int = 1) -> Written:
    """The page of the run or sweep folder ``source`` as ``output``/index.html, and with
    ``rerun`` a Rerun recording of a run (extra [viz]); ``workers``: processes that track a
    sweep's featured runs again."""
    if not source.is_dir():
        raise InputError(f"{source}: no such folder")
    if rerun is not None:
        _check_rerun(source, output, rerun)
    rendered = render_report(source, workers)
    if rerun is not None and rendered.run is None:
        raise InputError(f"--rerun: {source} is not a run folder (metrics.json)")
    recording = contextlib.nullcontext()
    if rerun is not None:
        from depotbench.eval.report.rerun import staged_recording

        recording = staged_recording(rendered.run, rerun)
    # The recording is written first (the longer write), renamed once the folder is in place.
    with StagedOutput(output, OutputKind.REPORT, overwrite=True) as staged, recording:
        write_text_atomic(staged.path / "index.html", rendered.text)
        staged.commit()
    return Written(output / "index.html", rerun, rendered.notes)
