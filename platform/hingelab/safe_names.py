"""Names that come from data become file names only through ``safe_file_name``.

An episode id, a dataset card's name or an id inside an export is a fact of a file, and a file
can say anything: ``../../x``, ``/etc/cron.d/job``, a newline, ten thousand characters. Every
path a command builds from such a fact joins a value that ``safe_file_name`` accepted: one path
component (no ``/`` or ``\\``), not ``.`` or ``..``, no control characters, not empty, at most
``MAX_NAME_CHARS`` characters. Anything else is refused with one line naming the file the value
came from and the field that holds it; ``unsafe_name_reason`` is the same check as a report
(``hingelab datasets verify`` lists such episodes).
"""

from __future__ import annotations

import unicodedata
from pathlib import Path

from hingelab.errors import HingelabError

MAX_NAME_CHARS = 128
SHOWN_CHARS = 60  # of a refused value, in the one-line error


class UnsafeNameError(HingelabError, ValueError):
    """A value read from data is not a plain file name, yet a path was to be built from it."""


def unsafe_name_reason(value) -> str | None:
    """None if ``value`` is a safe file name (see the module docstring), else why it is not."""
    if not isinstance(value, str):
        return f"is a {type(value).__name__}, not a string"
    if not value:
        return "is empty"
    if len(value) > MAX_NAME_CHARS:
        return f"is {len(value)} characters long (at most {MAX_NAME_CHARS})"
    if value in (".", ".."):
        return "names a folder itself (. or ..)"
    if "/" in value or "\\" in value:
        return "holds a path separator (/ or \\)" + (", an absolute path" if value[0] in "/\\" else "")
    if any(unicodedata.category(c) == "Cc" for c in value):  # NUL, newline, escape, DEL, C1 controls
        return "holds a control character"
    return None


def shown(value) -> str:
    """``value`` for a one-line message: repr (control characters escaped), long values cut."""
    text = repr(value)
    if len(text) > SHOWN_CHARS:
        text = f"{text[:SHOWN_CHARS]}... ({len(value) if isinstance(value, str) else len(text)} characters)"
    return text


def safe_file_name(value, what: str, source, fix: str = "rewrite that field, or leave the file out") -> str:
    """``value`` if it is a safe file name, else a one-line ``UnsafeNameError``.

    what: the field that holds it (``episode_id``, ``the dataset card's name``).
    source: the file (or flag) it was read from, named in the error.
    fix: what the user can do instead, ending the error.
    """
    reason = unsafe_name_reason(value)
    if reason is not None:
        raise UnsafeNameError(f"{source}: {what} {shown(value)} {reason}, so it cannot name a file or folder "
                              f"(a name from data must be one plain file name of at most {MAX_NAME_CHARS} "
                              f"characters); {fix}")
    return value


def safe_relative_path(value, what: str, source) -> Path:
    """A relative path read from data (``data/chunk-000/file-000.parquet``) whose every part is a
    safe file name: it cannot leave the folder it is joined to."""
    if not isinstance(value, str) or not value:
        safe_file_name(value, what, source)  # raises: not a string, or empty
    if value.startswith(("/", "\\")):
        raise UnsafeNameError(f"{source}: {what} {shown(value)} is an absolute path; a path from data must be "
                              "relative to the folder that holds it")
    for part in value.split("/"):
        reason = unsafe_name_reason(part)
        if reason is not None:
            raise UnsafeNameError(f"{source}: {what} {shown(value)} has the part {shown(part)}, which {reason}; "
                                  "a path from data must stay inside the folder that holds it")
    return Path(value)


__all__ = ["MAX_NAME_CHARS", "UnsafeNameError", "safe_file_name", "safe_relative_path", "unsafe_name_reason"]
