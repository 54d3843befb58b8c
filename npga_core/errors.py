"""The one error type for files the project reads, and the escaping every shown name goes through."""

from __future__ import annotations

import os
from pathlib import Path

#: Longest problem text of an error (a safety net: values in messages are shortened with `brief` already)
MAX_PROBLEM = 600


def shown(text: str | bytes | Path) -> str:
    """`text` safe to print, to draw in imgui or to pass to an encoder: printable characters kept, everything
    else (lone UTF-16 surrogates, undecodable bytes, newlines, control characters) as a backslash escape."""
    if isinstance(text, bytes):
        text = text.decode("utf-8", "surrogateescape")
    elif not isinstance(text, str):
        text = os.fspath(text) if isinstance(text, os.PathLike) else str(text)
        if isinstance(text, bytes):
            text = text.decode("utf-8", "surrogateescape")
    if text.isprintable() and text.isascii():
        return text
    return "".join(ch if ch.isprintable() and not 0xD800 <= ord(ch) <= 0xDFFF
                   else ch.encode("unicode_escape", "backslashreplace").decode("ascii") for ch in text)


def brief(value: object, limit: int = 60) -> str:
    """A value from an untrusted file, for an error message: never its repr (a YAML alias bomb's repr expands to
    gigabytes, an integer of 5000 digits cannot even be printed); strings and numbers shortened and escaped,
    containers named by their type and length only."""
    if isinstance(value, bool) or value is None:
        return str(value)
    if isinstance(value, int):
        return str(value) if value.bit_length() <= 64 else f"an integer of {value.bit_length()} bits"
    if isinstance(value, float):
        return f"{value:.6g}"
    if isinstance(value, str | bytes):
        text = shown(value[:limit])
        return repr(text) if len(value) <= limit else repr(text) + f"... ({len(value)} characters)"
    try:
        size = f" of {len(value)} items"  # type: ignore[arg-type]
    except TypeError:
        size = ""
    return f"a {type(value).__name__}{size}"


class AvatarFileError(Exception):
    """A file could not be read: ``str(err)`` is one line, "PATH: problem", both escaped with `shown`."""

    def __init__(self, path: str | Path, problem: str):
        self.path = shown(path)
        text = " ".join(str(problem)[:MAX_PROBLEM * 4].split())  # one line
        self.problem = shown(text if len(text) <= MAX_PROBLEM else text[:MAX_PROBLEM] + "...")
        super().__init__(f"{self.path}: {self.problem}")


class OutputError(AvatarFileError, OSError):
    """An output could not be written (a folder, FIFO or device in the way, a folder that cannot be made, no
    permission, a full disk): "PATH: problem" on one line; also an OSError for the callers that catch those."""


class CommandError(Exception):
    """Bad arguments of a command: one line (escaped), exit code 2, whatever the command."""

    def __init__(self, problem: str):
        super().__init__(shown(" ".join(str(problem).split())))
