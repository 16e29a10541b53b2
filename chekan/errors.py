"""Errors that name the file, the line and the problem."""

from __future__ import annotations

from os import PathLike


class ChekanError(Exception):
    """Base class of every error the package raises on purpose."""


class FormatError(ChekanError, ValueError):
    """Malformed input file: ``str(err)`` is ``"<file>:<line>: <problem>"``.

    ``line`` is 1-based; ``None`` when the problem concerns the whole file.
    """

    def __init__(self, path: str | PathLike | None, line: int | None, problem: str):
        self.path = str(path) if path is not None else "<input>"
        self.line = line
        self.problem = problem
        where = self.path if line is None else f"{self.path}:{line}"
        super().__init__(f"{where}: {problem}")


class ProgramError(ChekanError, ValueError):
    """Invalid tilt program (angle beyond the limit, negative dwell, empty program, …)."""
