"""Shared by the report scripts: write one ``## section`` of a Markdown file in ``docs/``.

Every report script takes ``--docs DIR`` (default: the repository's ``docs/``) and writes its
section(s) there, figures under ``DIR/figures/``; ``scripts/report.py`` runs them all, and the
test suite runs their ``--small`` versions into a temporary folder.
"""

from __future__ import annotations

import os
import pathlib
import tempfile

ROOT = pathlib.Path(__file__).resolve().parents[1]
DOCS = ROOT / "docs"


def write_section(path: pathlib.Path, heading: str, text: str) -> None:
    """Replace the section of ``path`` that starts with the line ``heading`` (or append it).

    ``text`` must start with ``heading``; the section ends at the next ``## `` line. Other
    sections are kept. The file is replaced atomically.
    """
    if not text.startswith(heading):
        raise ValueError(f"section text must start with {heading!r}")
    path = pathlib.Path(path)
    old = path.read_text(encoding="utf-8") if path.exists() else ""
    lines = old.splitlines(keepends=True)
    start = next((i for i, ln in enumerate(lines) if ln.rstrip("\n") == heading), None)
    text = text.rstrip("\n") + "\n"
    if start is None:
        sep = "" if not old or old.endswith("\n\n") else "\n" if old.endswith("\n") else "\n\n"
        new = old + sep + text
    else:
        end = next((i for i in range(start + 1, len(lines)) if lines[i].startswith("## ")), len(lines))
        new = "".join(lines[:start]) + text + ("\n" if end < len(lines) else "") + "".join(lines[end:])
    path.parent.mkdir(parents=True, exist_ok=True)
    fd, tmp = tempfile.mkstemp(dir=path.parent, prefix=f".{path.name}.")
    with os.fdopen(fd, "w", encoding="utf-8") as f:
        f.write(new)
    os.replace(tmp, path)


def figure_link(figure: pathlib.Path, doc: pathlib.Path) -> str:
    """Relative link from ``doc`` to ``figure``, for ``![...](link)``."""
    return os.path.relpath(figure, pathlib.Path(doc).parent).replace(os.sep, "/")
