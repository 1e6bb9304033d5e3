"""Help as a terminal shows it: plain text from the reStructuredText of docstrings, under the name
the command was typed with.

The commands' descriptions and option help come from docstrings written in reST (````code````,
``:func:`x```, ``*emphasis*``); :func:`plain` turns them into plain text before argparse wraps
them. ``odolab compare`` runs the same parser as ``python -m odolab.compare``: :func:`command_face`
names the face in use, and :class:`PlainHelp` shows it in ``usage:`` and in the description.
"""

from __future__ import annotations

import argparse
import contextvars
import functools
import re
from collections.abc import Iterator
from contextlib import contextmanager

__all__ = ["PlainHelp", "command_face", "plain", "plain_formatter"]

#: The name the running command was typed with (``odolab compare``), or None: its parser's own.
_FACE: contextvars.ContextVar[str | None] = contextvars.ContextVar("odolab_command_face", default=None)

_ROLE = re.compile(r":[\w:.-]+:`([^`<]*?)\s*(?:<[^`>]*>)?`")  # :func:`x`, :class:`~a.B`, :doc:`text <target>`
_LITERAL = re.compile(r"``(.+?)``")
_LINK = re.compile(r"`([^`<]+?)\s*(?:<[^`>]*>)?`__?")  # `text <url>`_ and `text`_
_DEFAULT_ROLE = re.compile(r"(?<![\w`])`([^`\s][^`]*)`(?![\w`])")
_STRONG = re.compile(r"(?<![\w*])\*\*([^*\s][^*]*?)\*\*(?![\w*])")
_EMPHASIS = re.compile(r"(?<![\w*])\*([^*\s][^*]*?)\*(?![\w*])")


def _role_target(match: re.Match) -> str:
    """A role's text; ``~a.b.C`` reads ``C`` (what Sphinx shows)."""
    text = match.group(1)
    return text[1:].rsplit(".", 1)[-1] if text.startswith("~") else text


def plain(text: str) -> str:
    """``text`` with reST inline markup taken out: ````code```` -> ``code``, ``:func:`~a.b``` ->
    ``b``, ```text <url>`_`` -> ``text``, ``*word*`` -> ``word``, a paragraph's closing ``::`` ->
    ``:``. Anything else is left as it is (``x1e-2 * 3``, ``a | b``)."""
    text = _ROLE.sub(_role_target, text)
    text = _LITERAL.sub(r"\1", text)
    text = _LINK.sub(r"\1", text)
    text = _DEFAULT_ROLE.sub(r"\1", text)
    text = _STRONG.sub(r"\1", text)
    text = _EMPHASIS.sub(r"\1", text)
    return re.sub(r"(?<=\S)::(?=\s*(\n|$))", ":", text)


@functools.cache
def plain_formatter(formatter: type[argparse.HelpFormatter]) -> type[argparse.HelpFormatter]:
    """``formatter`` (argparse's, or one of its kin) writing descriptions and option help as
    :func:`plain` text, before it wraps them."""

    class Plain(formatter):  # type: ignore[valid-type, misc]
        def _format_text(self, text: str) -> str:
            return super()._format_text(plain(text))

        def _expand_help(self, action: argparse.Action) -> str:
            return plain(super()._expand_help(action))

    Plain.__name__ = Plain.__qualname__ = f"Plain{formatter.__name__}"
    return Plain


@contextmanager
def command_face(name: str) -> Iterator[None]:
    """Parsers made inside the block show ``name`` (``odolab compare``) as their program, in
    ``usage:`` and wherever their description names the ``python -m`` form."""
    token = _FACE.set(name)
    try:
        yield
    finally:
        _FACE.reset(token)


class PlainHelp(argparse.ArgumentParser):
    """An argument parser whose help is plain text (:func:`plain_formatter`) under the name the
    command was typed with (:func:`command_face`)."""

    def __init__(self, *args, **kwargs) -> None:
        super().__init__(*args, **kwargs)
        self.formatter_class = plain_formatter(self.formatter_class)
        own, face = self.prog, _FACE.get()
        if face is not None and face != own:
            self.prog = face
            if self.description:
                self.description = self.description.replace(own, face)
            if self.epilog:
                self.epilog = self.epilog.replace(own, face)
