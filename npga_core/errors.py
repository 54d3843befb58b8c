"""The one error type for files the project reads."""

from __future__ import annotations

from pathlib import Path


class AvatarFileError(Exception):
    """A file could not be read: ``str(err)`` is one line, "PATH: problem"."""

    def __init__(self, path: str | Path, problem: str):
        self.path = str(path)
        self.problem = " ".join(str(problem).split())  # keep it on one line
        super().__init__(f"{self.path}: {self.problem}")
