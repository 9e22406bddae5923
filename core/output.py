"""Output folders that never lose a user's data.

Every folder depotbench writes goes through this module:

- **Staged and swapped.** A sequence or a run is written into a hidden sibling
  ``.NAME.partial-XXXXXXXX`` and swapped into place only when complete. On Linux the
  swap is one ``renameat2(RENAME_EXCHANGE)``, so a kill at any moment leaves either the
  old complete folder or the new one; elsewhere it is two renames, and the next writer
  puts the old folder back if a kill fell between them.
- **Marked.** A marker file (``.depotbench.json``) inside says that depotbench wrote the
  folder, what kind of output it is and, for sequences, the key of its content. It is
  written last, so it also means "complete". ``overwrite`` replaces only a folder that
  carries a marker of the same kind, and never the current directory, one of its
  ancestors, an input, or a folder holding an input.
- **Locked.** A lock file ``.NAME.lock`` beside the output (``flock``) keeps a second
  writer out and names the holder. The kernel releases it when the holder dies, so a
  stale lock file is simply free.
- **Cleaned.** The lock holder removes what killed writers of the same output left
  beside it; nobody else does, so a live writer's staging folder is never touched.
"""

from __future__ import annotations

import contextlib
import ctypes
import ctypes.util
import errno
import fcntl
import glob
import hashlib
import json
import os
import shutil
import socket
import stat
import sys
import tempfile
import time
import uuid
from dataclasses import asdict, dataclass
from enum import StrEnum
from pathlib import Path
from types import TracebackType

from depotbench.core.errors import InputError
from depotbench.core.files import read_json
from depotbench.core.processes import deliver_held

MARKER_NAME = ".depotbench.json"
MARKER_MAX_BYTES = 64 * 1024


class OutputKind(StrEnum):
    SEQUENCE = "sequence"
    RUN = "run"
    SUITE = "suite"
    DEMO = "demo"
    DATASET = "dataset"
    SWEEP = "sweep"
    REPORT = "report"
    ROSBAG = "rosbag"


class OutputError(InputError):
    """An output path that cannot, or must not, be written."""


@dataclass(frozen=True)
class Marker:
    """What the marker file of an output folder records."""

    kind: OutputKind
    content_key: str | None = None
    tool: str = "depotbench"

    def to_json(self) -> str:
        data = {**asdict(self), "kind": self.kind.value}
        return json.dumps(data, indent=2, sort_keys=True) + "\n"


def read_marker(folder: Path) -> Marker | None:
    """The folder's marker, or None when it has none (or one depotbench did not write)."""
    try:  # a FIFO (tar keeps them) would block a plain open until a writer came
        data = read_json(folder / MARKER_NAME, MARKER_MAX_BYTES, "depotbench marker")
        if data.get("tool") != "depotbench":
            return None
        return Marker(OutputKind(data["kind"]), data.get("content_key"))
    except (OSError, ValueError, KeyError, TypeError, AttributeError):  # FileError is a ValueError
        return None


# -- locks ------------------------------------------------------------------------


NAME_MAX_BYTES = 255
"""A file name's limit on Linux and macOS file systems."""
SIBLING_STEM_BYTES = 200
"""Hidden siblings (``.NAME.partial-1a2b3c4d``, ``.NAME.lock``) add up to 18 bytes to a
name: a longer one goes in shortened, so that every legal output name can be written."""


def hidden_sibling(target: Path, suffix: str) -> Path:
    """``target``'s hidden sibling ``.NAME<suffix>``; a name too long to take the suffix
    is shortened and marked with a hash of the whole, so that two long names never share
    a sibling."""
    name = target.name
    encoded = os.fsencode(name)
    if len(encoded) > SIBLING_STEM_BYTES:
        digest = hashlib.sha256(encoded).hexdigest()[:12]
        head = encoded[: SIBLING_STEM_BYTES - 13].decode("utf-8", "ignore")
        name = f"{head}~{digest}"
    return target.parent / f".{name}{suffix}"


def lock_path(target: Path) -> Path:
    return hidden_sibling(target, ".lock")


def _describe_holder(text: str) -> str:
    try:
        holder = json.loads(text)
        return f"pid {holder['pid']} on {holder['host']}, `{holder['command']}`, since {holder['started']}"
    except (ValueError, KeyError, TypeError):
        return "a process that is starting"


class OutputLock:
    """An exclusive ``flock`` on ``.NAME.lock`` beside an output, with the holder written in it."""

    def __init__(self, target: Path, wait: bool = False) -> None:
        self.target = target
        self.path = lock_path(target)
        self.wait = wait  # block until the holder lets go, instead of refusing
        self._fd: int | None = None

    def acquire(self) -> None:
        while True:
            fd = self._open()
            try:
                fcntl.flock(fd, fcntl.LOCK_EX | (0 if self.wait else fcntl.LOCK_NB))
            except BlockingIOError:
                holder = os.pread(fd, 4096, 0).decode("utf-8", "replace")
                os.close(fd)
                raise OutputError(
                    f"{self.target}: another depotbench is writing it ({_describe_holder(holder)}); "
                    "wait for it to finish or stop it"
                ) from None
            # The previous holder may have unlinked the file between our open and our lock:
            # then we hold a lock on a file nobody else can see, and must try again.
            try:
                same = os.lstat(self.path).st_ino == os.fstat(fd).st_ino
            except FileNotFoundError:
                same = False
            if same:
                break
            os.close(fd)
        holder = {
            "pid": os.getpid(),
            "host": socket.gethostname(),
            "command": " ".join(["depotbench", *sys.argv[1:]])[:300],
            "started": time.strftime("%Y-%m-%d %H:%M:%S"),
        }
        os.ftruncate(fd, 0)
        os.pwrite(fd, json.dumps(holder).encode(), 0)
        self._fd = fd

    def _open(self) -> int:
        """The lock file, opened without following a link and refused when it is another
        file's second name: it is truncated and written, and through a link planted in a
        shared folder that would overwrite the link's target."""
        try:
            fd = os.open(self.path, os.O_RDWR | os.O_CREAT | os.O_NOFOLLOW | os.O_NONBLOCK, 0o644)
        except OSError as exc:
            if exc.errno == errno.ELOOP:
                raise OutputError(
                    f"{self.path}: the lock file is a symbolic link; depotbench never writes through "
                    "one: remove it"
                ) from None
            raise OutputError(f"{self.target}: cannot write here ({exc.strerror})") from None
        info = os.fstat(fd)
        if not stat.S_ISREG(info.st_mode) or info.st_nlink > 1:
            os.close(fd)
            what = "not a regular file" if not stat.S_ISREG(info.st_mode) else "another file's second name"
            raise OutputError(f"{self.path}: the lock file is {what}; depotbench never writes it: remove it")
        os.set_blocking(fd, True)
        return fd

    def release(self) -> None:
        if self._fd is None:
            return
        with contextlib.suppress(FileNotFoundError):
            os.unlink(self.path)  # while still holding it: see acquire()
        os.close(self._fd)
        self._fd = None

    def __enter__(self) -> OutputLock:
        self.acquire()
        return self

    def __exit__(self, *exc: object) -> None:
        self.release()


# -- the checks every writer makes ---------------------------------------------------


def check_target(target: Path, inputs: tuple[Path, ...] = ()) -> Path:
    """The resolved target, refused when it is the working directory, an ancestor of it,
    an input, inside an input or a folder holding an input."""
    resolved = target.expanduser().resolve()
    cwd = Path.cwd().resolve()
    if resolved == cwd or resolved in cwd.parents:
        what = "the current directory" if resolved == cwd else "an ancestor of the current directory"
        raise OutputError(f"{target}: is {what}; give a new folder for the output")
    for item in inputs:
        source = item.expanduser().resolve()
        if resolved == source:
            what = "is the input"
        elif resolved in source.parents:
            what = f"is a folder holding the input {item}"
        elif source in resolved.parents:
            what = f"lies inside the input {item}"
        else:
            continue
        raise OutputError(f"{target}: {what}; give a separate folder for the output")
    return resolved


def _is_empty_dir(path: Path) -> bool:
    try:
        return path.is_dir() and not any(path.iterdir())
    except OSError:
        return False


def check_replaceable(target: Path, shown: Path, kind: OutputKind, overwrite: bool) -> None:
    """Refuse to replace anything but an empty folder or, with ``overwrite``, our own output."""
    if not (target.exists() or target.is_symlink()):
        return
    if not target.is_dir():
        raise OutputError(f"{shown}: is a file, not an output folder; give a folder path")
    if _is_empty_dir(target):
        return
    marker = read_marker(target)
    if marker is None:
        raise OutputError(
            f"{shown}: exists and was not written by depotbench (no {MARKER_NAME}); "
            "it is never replaced: give a new folder"
        )
    if marker.kind is not kind:
        raise OutputError(
            f"{shown}: is a depotbench {marker.kind.value} output, not a {kind.value} output; "
            "give another folder"
        )
    if not overwrite:
        raise OutputError(f"{shown}: already exists (pass --overwrite to replace it)")


# -- the atomic swap -------------------------------------------------------------------

_RENAME_EXCHANGE = 2
_AT_FDCWD = -100


def _renameat2():
    if not sys.platform.startswith("linux"):
        return None
    try:
        libc = ctypes.CDLL(ctypes.util.find_library("c") or None, use_errno=True)
        function = libc.renameat2
    except (OSError, AttributeError):
        return None
    function.argtypes = [ctypes.c_int, ctypes.c_char_p, ctypes.c_int, ctypes.c_char_p, ctypes.c_uint]
    function.restype = ctypes.c_int
    return function


_RENAMEAT2 = _renameat2()


def exchange(a: Path, b: Path) -> bool:
    """Swap two folders in one atomic step; False where the system cannot."""
    if _RENAMEAT2 is None:
        return False
    result = _RENAMEAT2(_AT_FDCWD, os.fsencode(a), _AT_FDCWD, os.fsencode(b), _RENAME_EXCHANGE)
    if result == 0:
        return True
    code = ctypes.get_errno()
    if code in (errno.EINVAL, errno.ENOSYS, errno.ENOTSUP, errno.EOPNOTSUPP):
        return False  # this file system cannot exchange: fall back to two renames
    raise OSError(code, os.strerror(code), str(b))


def _leftovers(target: Path, tag: str) -> list[Path]:
    pattern = glob.escape(hidden_sibling(target, f".{tag}-").name) + "*"
    return sorted(target.parent.glob(pattern))


def recover_and_clean(target: Path) -> None:
    """Undo what killed writers of ``target`` left; the caller holds the target's lock.

    An old folder set aside by the two-rename swap goes back if the new one never
    arrived; every other leftover (staging folders, set-aside folders) is removed.
    """
    olds = [p for p in _leftovers(target, "old") if read_marker(p) is not None]
    if olds and not target.exists():
        os.replace(olds[0], target)
    for stale in _leftovers(target, "old") + _leftovers(target, "partial"):
        shutil.rmtree(stale, ignore_errors=True)


def clean_if_unowned(target: Path) -> bool:
    """Clean what killed writers of ``target`` left, unless a live writer holds it (then False).

    For containers, whose outputs may be complete already (so never written again).
    """
    lock = OutputLock(target)
    try:
        lock.acquire()
    except OutputError:
        return False
    try:
        recover_and_clean(target)
    finally:
        lock.release()
    return True


def replace_folder(new: Path, target: Path) -> None:
    """Put the complete folder ``new`` at ``target``; an old one goes only after the swap."""
    if not target.exists():
        os.rename(new, target)
        return
    if exchange(new, target):
        shutil.rmtree(new)  # ``new`` now holds the old output
        return
    old = hidden_sibling(target, f".old-{uuid.uuid4().hex[:8]}")
    os.rename(target, old)
    os.rename(new, target)
    shutil.rmtree(old)


def _os_error(path: Path, exc: OSError) -> OutputError:
    return OutputError(f"{path}: cannot write the output ({exc.strerror or exc})")


# -- the writers' context managers ---------------------------------------------------------


def _claim(shown: Path, inputs: tuple[Path, ...]) -> tuple[Path, OutputLock]:
    """Check a target, make its parent and take its lock: what every writer does first."""
    deliver_held()  # a Ctrl-C from the imports ends the command before it writes
    target = check_target(shown, inputs)
    try:
        target.parent.mkdir(parents=True, exist_ok=True)
    except OSError as exc:
        raise _os_error(shown, exc) from None
    lock = OutputLock(target)
    lock.acquire()
    return target, lock


class StagedOutput:
    """A folder written beside its target and swapped into place by ``commit()``.

    ``with StagedOutput(target, kind) as out:`` checks the target, takes its lock,
    cleans leftovers and creates ``out.path`` (so an unwritable place is found before
    any work). Leaving the block without ``commit()`` removes everything it wrote.
    """

    def __init__(
        self,
        target: Path | str,
        kind: OutputKind,
        *,
        overwrite: bool = False,
        inputs: tuple[Path, ...] = (),
        content_key: str | None = None,
    ) -> None:
        self.shown = Path(target)
        self.kind = kind
        self.overwrite = overwrite
        self.inputs = inputs
        self.content_key = content_key
        self.target = self.shown
        self._lock: OutputLock | None = None
        self._path: Path | None = None

    @property
    def path(self) -> Path:
        if self._path is None:
            raise RuntimeError("StagedOutput must be entered before use")
        return self._path

    def __enter__(self) -> StagedOutput:
        self.target, self._lock = _claim(self.shown, self.inputs)
        try:
            recover_and_clean(self.target)
            check_replaceable(self.target, self.shown, self.kind, self.overwrite)
            staging = hidden_sibling(self.target, f".partial-{uuid.uuid4().hex[:8]}")
            try:
                staging.mkdir()
            except OSError as exc:
                raise _os_error(self.shown, exc) from None
            self._path = staging
        except BaseException:
            self._lock.release()
            raise
        return self

    def commit(self) -> None:
        """Mark the staged folder complete and swap it into place."""
        path = self.path
        try:
            (path / MARKER_NAME).write_text(Marker(self.kind, self.content_key).to_json(), encoding="utf-8")
            replace_folder(path, self.target)
        except OSError as exc:
            raise _os_error(self.shown, exc) from None
        self._path = None

    def __exit__(
        self,
        exc_type: type[BaseException] | None,
        exc: BaseException | None,
        tb: TracebackType | None,
    ) -> None:
        try:
            if self._path is not None:
                shutil.rmtree(self._path, ignore_errors=True)
                self._path = None
        finally:
            if self._lock is not None:
                self._lock.release()
        if isinstance(exc, OSError) and _failed_write(exc, self.target.parent):
            raise _os_error(self.shown, exc) from None


class OutputContainer:
    """A folder that collects outputs (a suite's sequences, the demo's runs), locked while in use.

    It is created in place with its marker; an existing one is reused only when it is
    empty or carries a marker of the same kind.
    """

    def __init__(self, target: Path | str, kind: OutputKind, *, inputs: tuple[Path, ...] = ()) -> None:
        self.shown = Path(target)
        self.kind = kind
        self.inputs = inputs
        self.path = self.shown
        self._lock: OutputLock | None = None
        self._created = False

    def __enter__(self) -> OutputContainer:
        self.path, self._lock = _claim(self.shown, self.inputs)
        try:
            if self.path.exists() and not _is_empty_dir(self.path):
                check_replaceable(self.path, self.shown, self.kind, overwrite=True)
            try:
                self._created = not self.path.exists()
                self.path.mkdir(exist_ok=True)
                if read_marker(self.path) is None:
                    write_text_atomic(self.path / MARKER_NAME, Marker(self.kind).to_json())
            except OSError as exc:
                raise _os_error(self.shown, exc) from None
        except BaseException:
            self._lock.release()
            raise
        return self

    def __exit__(
        self,
        exc_type: type[BaseException] | None,
        exc: BaseException | None,
        tb: TracebackType | None,
    ) -> None:
        if exc is not None and self._created:
            self._remove_if_unused()
        if self._lock is not None:
            self._lock.release()
        if isinstance(exc, OSError) and _failed_write(exc, self.path):
            raise _os_error(self.shown, exc) from None

    def _remove_if_unused(self) -> None:
        """A container this run made and that holds nothing but its marker after a failure
        goes again: a failed command leaves no empty output behind."""
        try:
            if [p.name for p in self.path.iterdir()] == [MARKER_NAME]:
                (self.path / MARKER_NAME).unlink()
                self.path.rmdir()
        except OSError:
            pass  # something else appeared in it meanwhile: it stays, as any output would


WRITE_FAILURES = (errno.ENOSPC, errno.EDQUOT, errno.EFBIG, errno.EROFS)
"""What a write into a full, capped or read-only file system fails with."""


def _failed_write(exc: OSError, place: Path) -> bool:
    """Whether ``exc`` is a write into the output failing (a full disk, say), to be told as
    such: ``write()`` names no file, and a copy names its source, not where it wrote."""
    if exc.errno not in WRITE_FAILURES:
        return False
    written = getattr(exc, "filename2", None) or exc.filename
    if written is None:
        return True
    try:
        return place.resolve() in Path(os.fsdecode(written)).resolve().parents
    except (OSError, TypeError, ValueError):
        return False


def check_output_file(
    path: Path, *, overwrite: bool, inputs: tuple[Path, ...] = (), option: str = ""
) -> None:
    """Refuse, before any work, an output file that must not or cannot be written.

    An input, or a file inside an input folder, is never replaced; an existing file only
    with ``overwrite``; a folder, a device or a link's target never. The folder is made
    if missing, and must take a new file: that is tried (a file created and removed),
    since permission bits do not tell (root may write anywhere but ``/proc``).
    """
    shown = f"{option} {path}".strip()
    resolved = path.expanduser().resolve()
    for item in inputs:
        source = item.expanduser().resolve()
        if resolved == source or source in resolved.parents:
            what = "is the input" if resolved == source else f"lies inside the input {item}"
            raise OutputError(f"{shown}: {what}; give another file for the output")
    if path.is_dir():
        raise OutputError(f"{shown}: is a folder; give a file name")
    if path.is_symlink():
        raise OutputError(f"{shown}: is a symbolic link; give a plain file name")
    if path.exists():
        if not path.is_file():
            raise OutputError(f"{shown}: is not a regular file (a device, pipe or socket)")
        if not overwrite:
            raise OutputError(f"{shown}: already exists (pass --overwrite to replace it)")
    folder = resolved.parent
    try:  # CI writes reports into folders a clean clone lacks (``--junit reports/gates.xml``)
        folder.mkdir(parents=True, exist_ok=True)
    except FileExistsError:
        raise OutputError(f"{shown}: {folder} is not a folder") from None
    except OSError as exc:
        raise OutputError(f"{shown}: cannot make the folder {folder} ({exc.strerror or exc})") from None
    try:
        handle, probe = tempfile.mkstemp(
            prefix=hidden_sibling(resolved, ".").name, suffix=".probe", dir=folder
        )
        os.close(handle)
        os.unlink(probe)
    except OSError as exc:
        raise OutputError(f"{shown}: cannot write in {folder} ({exc.strerror or exc})") from None


def write_bytes_atomic(path: Path, data: bytes) -> None:
    """Write a file through a temporary sibling, so it is never seen half-written."""
    tmp = hidden_sibling(path, f".{uuid.uuid4().hex[:8]}.tmp")
    try:
        tmp.write_bytes(data)
        os.replace(tmp, path)
    except OSError as exc:
        tmp.unlink(missing_ok=True)
        raise _os_error(path, exc) from None


def write_text_atomic(path: Path, text: str) -> None:
    write_bytes_atomic(path, text.encode("utf-8"))
