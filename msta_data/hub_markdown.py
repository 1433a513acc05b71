"""Text from users and files, written into a card so that it renders as the text it is.

A card's body is Markdown that the hub renders to HTML. Names and values it shows come from
the person pushing or from files (metric and condition names, a tag, a dataset repo, a
policy name from msta-eval's metrics.json): written as they are, ``<script>`` or
``<img onerror=...>`` would be HTML in the page, ``# x`` a heading, ``[x](url)`` a link and
``|`` a new table cell. :func:`text` makes any string inert Markdown text, :func:`code` an
inline code span, :func:`shell` a shell word and :func:`python_str` a Python string literal
(what a copied command or snippet then reads is exactly the value).
"""

from __future__ import annotations

import html
import json
import re
import shlex

#: Characters Markdown (CommonMark, GitHub's tables) gives a meaning anywhere in a line,
#: escaped with a backslash: code, emphasis, links and images, headings, table cells. An
#: underscore inside a word (``lin_tracking``) means nothing and stays as it is.
_SPECIAL = re.compile(r"([\\`*\[\]()#|~]|(?<![A-Za-z0-9])_|_(?![A-Za-z0-9]))")
#: What starts a list or a heading underline at the start of a line (a quote's ``>`` is an
#: entity already).
_LEADING = re.compile(r"^([-+=]|\d+[.)])")
#: What would become a link by itself (GitHub's autolinks: ``www.``, ``scheme://``).
_AUTOLINK = re.compile(r"(?i)(www)\.|(://)")


def _one_line(value: object) -> str:
    return " ".join(str(value).split())


def text(value: object) -> str:
    """``value`` as inert Markdown text on one line: HTML characters as entities, Markdown's
    punctuation escaped, whitespace (newlines included) collapsed to single spaces."""
    out = _SPECIAL.sub(r"\\\1", _one_line(value))
    out = _LEADING.sub(lambda m: m.group(1)[:-1] + "\\" + m.group(1)[-1], out)
    out = html.escape(out, quote=False)
    return _AUTOLINK.sub(lambda m: "www&#46;" if m.group(1) else "&#58;//", out)


def code(value: object, in_table: bool = False) -> str:
    """``value`` as an inline code span (shown verbatim: no HTML, no Markdown inside), on one
    line; delimited by a backtick run longer than any in ``value``. ``in_table``: a ``|``
    is escaped as GitHub's tables need even inside code."""
    body = _one_line(value)
    run = max((len(m) for m in re.findall(r"`+", body)), default=0) + 1
    if in_table:
        body = body.replace("|", "\\|")
    pad = " " if body.startswith("`") or body.endswith("`") or run > 1 else ""
    return f"{'`' * run}{pad}{body}{pad}{'`' * run}"


def shell(value: object) -> str:
    """``value`` as one shell word (quoted when it holds anything the shell would read)."""
    return shlex.quote(str(value))


def python_str(value: object) -> str:
    """``value`` as a Python string literal (a JSON string is one)."""
    return json.dumps(str(value))
