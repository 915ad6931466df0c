"""A griffe extension for the API reference (mkdocs.yml): docstrings write units in brackets, "[m]",
and Markdown reads a bracketed group followed by another, "[(s, x, y), ...] [m]", as a reference
link. This escapes the second bracket so that the text shows as written."""

import re

import griffe

_TWO_GROUPS = re.compile(r"\](\s)\[")


class UnitBrackets(griffe.Extension):
    """Escape "] [" in every docstring: a unit after a bracketed group is text, not a link."""

    def on_object(self, *, obj: griffe.Object, **kwargs) -> None:
        if obj.docstring is not None:
            obj.docstring.value = _TWO_GROUPS.sub(r"]\1\\[", obj.docstring.value)
