"""The typed error the library raises for a value its caller gave and it cannot use.

The library does not know whether the value came from a command-line option, a TOML file or a
Python call, so it words the problem after a name the caller chooses: the command lines
(:mod:`odolab.cli`) name their option, ``err.named("--odometers")`` -> ``"--odometers is empty"``;
``str(err)`` uses the error's own ``subject`` (``"odometer list is empty"``).
"""

from __future__ import annotations

__all__ = ["InputError"]


class InputError(ValueError):
    """A value that cannot be used: ``problem`` says why, following the value's name after ``joiner``
    (``" "``: ``"<name> is empty"``; ``": "``: ``"<name>: 'x' is named twice"``)."""

    #: What the value is, in the library's words (subclasses name theirs).
    subject = "input"

    def __init__(self, problem: str, joiner: str = " ", subject: str | None = None) -> None:
        self.problem = problem
        self.joiner = joiner
        if subject is not None:
            self.subject = subject
        super().__init__(self.named(self.subject))

    def named(self, name: str) -> str:
        """The message with the value called ``name`` (e.g. the command-line option that gave it)."""
        return f"{name}{self.joiner}{self.problem}"
