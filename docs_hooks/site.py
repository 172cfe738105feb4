"""MkDocs hooks of the documentation site (``mkdocs.yml``, ``make docs``).

- The API reference is generated from ``ctfit/__init__.pyi``, the one list of public names: a
  page per concern (the subpackage a name comes from), each name a ``::: ctfit.<name>`` block for
  mkdocstrings, so the reference cannot miss a name or keep a removed one. The pages are added
  to the nav under "API reference".
- The notebooks of ``notebooks/`` are added as pages where they are (no copy in ``docs/``);
  mkdocs-jupyter renders them from their stored outputs.
- The README, the changelog and the guides name each other by their path in the repository, as
  code (`` `docs/fitting.md` ``, read as such on GitHub or in a terminal); on the site each such
  name of a page becomes a link to it.
"""

from __future__ import annotations

import ast
import pathlib
import re

from mkdocs.plugins import event_priority
from mkdocs.structure.files import File

ROOT = pathlib.Path(__file__).resolve().parents[1]
STUB = ROOT / "ctfit" / "__init__.pyi"
API_NAV = "API reference"
PAGE_PATH = re.compile(r'(?<!">)<code>((?:docs|notebooks)/[\w./-]+\.(?:md|ipynb))</code>')
TITLES = {  # each concern's page, in the layers' order; a new subpackage comes last, under its folder's name
    "_model": "Model",
    "_io": "Files and formats",
    "_runtime": "Runtime",
    "_colour": "Colour",
    "_fitting": "Fitting",
    "_render": "Rendering",
    "_export": "Export",
    "_sampling": "Posterior sampling",
}


def public_names() -> dict[str, list[str]]:
    """subpackage → its public names, in the order ``ctfit/__init__.pyi`` lists them."""
    names: dict[str, list[str]] = {}
    for node in ast.parse(STUB.read_text(encoding="utf-8")).body:
        if isinstance(node, ast.ImportFrom) and node.level == 1:
            names.setdefault(node.module, []).extend(alias.asname or alias.name for alias in node.names)
    return names


def api_pages() -> dict[str, tuple[str, str]]:
    """``api/<concern>.md`` → (title, Markdown) for each subpackage with public names, and ``api/index.md``."""
    pages, rows = {}, []
    order = list(TITLES)
    for package, names in sorted(public_names().items(), key=lambda item: order.index(item[0]) if item[0] in order else len(order)):
        title = TITLES.get(package, package.strip("_").capitalize())
        summary = ast.get_docstring(ast.parse((ROOT / "ctfit" / package / "__init__.py").read_text(encoding="utf-8"))) or ""
        summary = summary.split("\n\n")[0].replace("\n", " ")
        uri = f"api/{package.strip('_')}.md"
        blocks = "\n\n".join(f"::: ctfit.{name}" for name in names)
        pages[uri] = (title, f"# {title}\n\n{summary}\n\n{blocks}\n")
        rows.append(f"| [{title}]({uri.removeprefix('api/')}) | {summary} | {len(names)} |")
    index = ("# API reference\n\nEvery public name of `ctfit`, by concern (`import ctfit`, then "
             "`ctfit.<name>`). Each example in a docstring is run by the test suite.\n\n"
             "| concern | what it holds | names |\n|---|---|---|\n" + "\n".join(rows) + "\n")
    return {"api/index.md": (API_NAV, index), **pages}


def on_config(config):
    """The nav entry ``API reference: api/index.md`` becomes a section of the generated pages."""
    nav = config["nav"] or []
    for i, entry in enumerate(nav):
        if isinstance(entry, dict) and entry.get(API_NAV) == "api/index.md":
            nav[i] = {API_NAV: [{title: uri} for uri, (title, _) in api_pages().items()]}
    return config


@event_priority(50)  # before mkdocs-jupyter's on_files, which takes the notebooks over
def on_files(files, config):
    for uri, (_, text) in api_pages().items():
        files.append(File.generated(config, uri, content=text))
    for notebook in sorted((ROOT / "notebooks").glob("*.ipynb")):
        files.append(File(f"notebooks/{notebook.name}", src_dir=str(ROOT), dest_dir=config["site_dir"],
                          use_directory_urls=config["use_directory_urls"]))
    return files



def on_page_content(html, page, config, files):
    """Each ``<code>docs/<page>.md</code>`` or ``<code>notebooks/<name>.ipynb</code>`` that names a page
    of the site and is not a link already, linked (in the HTML: the README and the changelog come in
    through snippets, after the Markdown hooks, and the API pages through mkdocstrings)."""

    def link(match):
        target = files.get_file_from_path(match.group(1).removeprefix("docs/"))
        if target is None or not target.is_documentation_page():
            return match.group(0)
        return f'<a href="{target.url_relative_to(page.file)}">{match.group(0)}</a>'

    return PAGE_PATH.sub(link, html)
