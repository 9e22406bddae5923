"""Errors for bad input: each names the file and, where known, the line.

``InputError`` marks a user's mistake (the CLI prints it in one line and exits
with code 2); any other exception is a bug of ours and keeps its traceback.
"""

from __future__ import annotations

from pathlib import Path


class InputError(ValueError):
    """Bad input from the user: a file, a field or an argument."""

    def __reduce__(self):
        """Rebuilt from its message and fields, not by calling ``__init__`` with the message
        alone: worker processes and Ray send errors back pickled, and ``FileError(message)``
        raised TypeError there, so a bad file in a Ray job reached the user as a 30-line
        ``UnserializableException``."""
        return (_rebuilt, (type(self), self.args, self.__dict__))


def _rebuilt(kind: type[BaseException], args: tuple, fields: dict) -> BaseException:
    error = kind.__new__(kind, *args)
    error.args = args
    error.__dict__.update(fields)
    return error


class FileError(InputError):
    """A file that cannot be used as input: the message names it and, where known, the line."""

    def __init__(self, path: Path | str, line: int | None, problem: str) -> None:
        self.path = Path(path)
        self.line = line
        self.problem = problem
        where = f"{self.path}" if line is None else f"{self.path}:{line}"
        super().__init__(f"{where}: {problem}")


class SequenceFormatError(FileError):
    """A folder or file breaks the sequence format (docs/format.md)."""


class ScenarioError(InputError):
    """A spec that validates but cannot be built (no free path among the props, say)."""


class EnvironmentProblem(RuntimeError):
    """The machine lacks something the user can install (a GL library, say)."""
