"""The one error type for files the project reads, and the escaping every shown name goes through."""

from __future__ import annotations

import os
from pathlib import Path


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


class AvatarFileError(Exception):
    """A file could not be read: ``str(err)`` is one line, "PATH: problem", both escaped with `shown`."""

    def __init__(self, path: str | Path, problem: str):
        self.path = shown(path)
        self.problem = shown(" ".join(str(problem).split()))  # keep it on one line
        super().__init__(f"{self.path}: {self.problem}")
