"""MkDocs hook: the docstrings are written for Sphinx-style readers (``:class:`~a.B```, ``text::``);
mkdocstrings renders them as Markdown, so those roles and literal-block markers are tidied here."""

from __future__ import annotations

import re

_ROLES = r"(?:class|meth|func|data|attr|mod|exc|obj)"
_ROLE = re.compile(rf":{_ROLES}:<code>(~?)([^<]*)</code>")
# Inside a code span (a parameter's description in a table) the role is left as typed.
_RAW_ROLE = re.compile(rf":{_ROLES}:`(~?)([^`]*)`")
_LONE_MARKER = re.compile(r"<p>::</p>\s*")
_TRAILING_MARKER = re.compile(r"::</p>")


def _role(match: re.Match[str]) -> str:
    short, target = match.group(1), match.group(2)
    return f"<code>{target.rsplit('.', 1)[-1] if short else target}</code>"


def on_page_content(html: str, **_: object) -> str:
    """Turn Sphinx roles into plain code and drop reST's ``::`` literal-block markers."""
    html = _ROLE.sub(_role, html)
    html = _RAW_ROLE.sub(lambda m: _role(m).replace("<code>", "").replace("</code>", ""), html)
    html = _LONE_MARKER.sub("", html)
    return _TRAILING_MARKER.sub(":</p>", html)
