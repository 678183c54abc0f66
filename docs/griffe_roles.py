"""A griffe extension for the API reference (mkdocstrings, ``mkdocs.yml``): the site
renders docstrings as Markdown, where the Sphinx roles they use (``:class:`Rigid```,
``:func:`~acq.log.reader.read_metadata```) would show as typed. Each becomes the code
span of what it names (``~``: its last part, as Sphinx shows it)."""

from __future__ import annotations

import re
from typing import Any

import griffe

ROLE = re.compile(r":(?:py:)?(?:class|func|meth|mod|attr|data|exc|obj|const):`(~?)([^`]+)`")


def plain(text: str) -> str:
    """``text`` with each Sphinx role as a Markdown code span of its target."""

    def code(m: re.Match[str]) -> str:
        target = m.group(2).rsplit(".", 1)[-1] if m.group(1) else m.group(2)
        return f"`{target}`"

    return ROLE.sub(code, text)


class SphinxRoles(griffe.Extension):
    """Rewrites the roles of every docstring loaded."""

    def on_object(self, *, obj: griffe.Object, **kwargs: Any) -> None:
        if not obj.is_alias and obj.docstring is not None:
            obj.docstring.value = plain(obj.docstring.value)
