"""A path as text that every store and page can hold, and back, losslessly.

A Linux file name is bytes; Python reads one that is not UTF-8 into a ``str`` holding lone
surrogates (PEP 383), which SQLite, JSON written as UTF-8 and HTML all refuse
(``UnicodeEncodeError`` in a sweep's row insert). ``path_text`` writes such a path with each
byte that is not UTF-8 as ``\\xNN`` and each backslash doubled; a UTF-8 path without a
backslash, nearly every path, stays as it is, so rows already stored keep their text.
"""

from __future__ import annotations

import os
import re
from pathlib import Path

_ESCAPE = re.compile(r"\\(\\|x[0-9a-f]{2})")


def path_text(path: Path | str) -> str:
    """``path`` as UTF-8-encodable text that ``text_path`` turns back into the same path."""
    raw = os.fsencode(path)
    try:
        text = raw.decode("utf-8")
    except UnicodeDecodeError:
        text = None
    if text is not None and "\\" not in text:
        return text
    escaped = raw.replace(b"\\", b"\\\\").decode("utf-8", "backslashreplace")
    return escaped


def text_path(text: str) -> Path:
    """The path ``path_text`` wrote as ``text``."""
    if "\\" not in text:
        return Path(text)

    def byte(match: re.Match[str]) -> str:
        token = match.group(1)
        return "\\" if token == "\\" else os.fsdecode(bytes([int(token[1:], 16)]))

    return Path(_ESCAPE.sub(byte, text))
