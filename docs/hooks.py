"""mkdocs hooks for the geovox site (``hooks:`` in mkdocs.yml).

The docstrings use Sphinx cross-reference roles (``:func:`voxelize```) where a reader of the
source expects them; mkdocstrings renders Markdown, in which the role's name would be left
standing in front of the code. The role names are dropped from the rendered HTML, leaving the
code span.
"""

import re

_ROLE = re.compile(r":(?:py:)?(?:mod|func|class|meth|attr|data|exc|obj|const|term):(?=<code>)")


def on_page_content(html, **kwargs):
    return _ROLE.sub("", html)
