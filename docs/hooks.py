"""MkDocs hook: the docstrings' Sphinx roles (``:class:`Simulator```) read as code in the API
reference. mkdocstrings renders the backquoted name as code and leaves the role's prefix as
text ("use :class:Simulator"); this drops the prefix, and the ``~`` that shortens a path."""

from __future__ import annotations

import re

_ROLE = re.compile(r":(?:py:)?(?:class|func|meth|mod|attr|data|exc|obj|const|ref|term):(<code>)~?")


def on_page_content(html: str, **kwargs) -> str:
    """Drop the role prefixes before code spans (every page: only docstrings have them)."""
    return _ROLE.sub(r"\1", html)
