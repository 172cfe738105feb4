"""Names that are text: a measurement's ``source`` and a material's ``name`` as valid Unicode.

Python holds the name of a file that is not UTF-8 (Latin-1 bytes, say) as lone surrogates
(``os.fsdecode``), which no UTF-8 text holds: a fit-result document, a CSV's ``#`` line, an
exported file, a plot's title (matplotlib refuses them) or a strict terminal would fail on them.
A name is held with those bytes as U+FFFD, as a terminal shows them.
"""

from __future__ import annotations

__all__ = ["valid_name"]


def valid_name(text: str) -> str:
    r"""``text`` with the undecodable bytes of a file name (lone surrogates U+DC80–U+DCFF) as
    U+FFFD, and any other lone surrogate as ``?``; valid text unchanged.

    >>> valid_name("caf\udce9.csv") == "caf\ufffd.csv", valid_name("café.csv")
    (True, 'café.csv')
    """
    try:
        text.encode("utf-8")
        return text
    except UnicodeEncodeError:
        pass
    try:
        return text.encode("utf-8", "surrogateescape").decode("utf-8", "replace")
    except UnicodeEncodeError:
        return text.encode("utf-8", "replace").decode("utf-8")
