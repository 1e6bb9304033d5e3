"""The one error type of odolab's file readers: it names the file, the line and the problem."""

from __future__ import annotations

import os

__all__ = ["FileFormatError"]


class FileFormatError(ValueError):
    """A file that cannot be read as the format it should have.

    ``str(err)`` is e.g. ``"groundtruth.txt, line 7: expected 8 columns, got 6"``, or
    ``"groundtruth.txt: no such file"`` when the problem is not on one line (``line_no`` None).
    """

    def __init__(self, path: str | os.PathLike, line_no: int | None, problem: str) -> None:
        self.path = os.fspath(path)
        self.line_no = line_no
        self.problem = problem
        super().__init__(path, line_no, problem)

    def __str__(self) -> str:
        where = self.path if self.line_no is None else f"{self.path}, line {self.line_no}"
        return f"{where}: {self.problem}"
