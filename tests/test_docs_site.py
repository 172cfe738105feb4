"""The documentation site (``mkdocs.yml``, ``make docs``; issue 24): it builds with no warning, its
API reference holds every public name, every link in it resolves, and its front page renders in
a browser (headless Chromium, the Debian package)."""

import ast
import html.parser
import importlib.util
import os
import re
import subprocess
import sys
from pathlib import Path
from urllib.parse import unquote, urlsplit

import numpy as np
import pytest
from PIL import Image

from conftest import ROOT

CHROMIUM = Path("/usr/bin/chromium")
INSTALL_CHROMIUM = "sudo apt-get install -y --no-install-recommends chromium (Debian's package; .ci/run installs it)"
NOTEBOOKS = sorted(p.stem for p in (ROOT / "notebooks").glob("*.ipynb"))


def _module(name: str, path: Path):
    spec = importlib.util.spec_from_file_location(name, path)
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


def _public_names() -> set[str]:
    tree = ast.parse((ROOT / "ctfit" / "__init__.pyi").read_text(encoding="utf-8"))
    return {a.asname or a.name for node in tree.body if isinstance(node, ast.ImportFrom) for a in node.names}


def test_the_api_pages_hold_every_public_name_once():
    """The generated reference (``docs_hooks/site.py``) has one ``::: ctfit.<name>`` block per public
    name of ``ctfit/__init__.pyi``, and its index links every page."""
    pages = _module("docs_site_hooks", ROOT / "docs_hooks" / "site.py").api_pages()
    blocks = re.findall(r"^::: ctfit\.(\w+)$", "".join(text for _, text in pages.values()), flags=re.M)
    assert sorted(blocks) == sorted(_public_names())
    index = pages["api/index.md"][1]
    assert all(f"]({uri.removeprefix('api/')})" in index for uri in pages if uri != "api/index.md")


def test_doctests_in_the_text_are_fenced_and_examples_sections_left_to_mkdocstrings():
    fence = _module("docs_griffe_ctfit", ROOT / "docs_hooks" / "griffe_ctfit.py").fence_doctests
    text = 'Reads a table.\n\n>>> t = read("Au")\n>>> t["meta"]["material"]\n\'Gold\'\n\nMore text.'
    assert fence(text) == 'Reads a table.\n\n```pycon\n>>> t = read("Au")\n>>> t["meta"]["material"]\n\'Gold\'\n```\n\nMore text.'
    numpy_style = "Reads a table.\n\nExamples\n--------\n>>> t = read('Au')\n"
    assert fence(numpy_style) == numpy_style
    assert fence("a >>> b\n") == "a >>> b\n"  # only a paragraph that starts with >>>


def test_the_griffe_extension_resolves_lazy_exports_and_links_only_what_the_site_shows():
    import griffe

    extension = _module("docs_griffe_ctfit", ROOT / "docs_hooks" / "griffe_ctfit.py")
    ext = extension.CtfitSite()
    pkg = griffe.load("ctfit", search_paths=[str(ROOT)], extensions=griffe.load_extensions(ext), resolve_aliases=False)
    assert pkg["fit"].final_target.path == "ctfit._fitting.least_squares.fit"  # through ctfit._fitting's lazy table
    assert Path(pkg["fit"].final_target.filepath).is_relative_to(ROOT)  # this checkout's code
    model = pkg["_model"]
    assert ext.site_path(model, "ctfit.fit") == "ctfit.fit"
    assert ext.site_path(model, "Measurement.directions") == "ctfit.Measurement.directions"  # a documented method
    assert ext.site_path(pkg, "ctfit._fitting.solvers.StructuredLevenbergMarquardt") is None  # private: not on the site
    assert ext.site_path(model, "numpy.asarray") is None and ext.site_path(model, "no_such_name") is None
    convert = lambda text: extension.ROLE.sub(lambda m: ext.role(model, m), text)
    assert convert("see :func:`~ctfit.fit` and :class:`ctfit.Material`") == "see [`fit`][ctfit.fit] and [`ctfit.Material`][ctfit.Material]"
    assert convert(":mod:`ctfit._io.files`, :func:`_private()`") == "`ctfit._io.files`, `_private`"
    assert ":func:" not in pkg["_fitting"]["least_squares"]["fit"].docstring.value  # converted when loaded


class _Links(html.parser.HTMLParser):
    def __init__(self):
        super().__init__()
        self.links, self.ids = [], set()

    def handle_starttag(self, tag, attrs):
        attrs = dict(attrs)
        self.ids |= {attrs[k] for k in ("id", "name") if attrs.get(k)}
        for key in ("href", "src"):
            if attrs.get(key) is not None and not (tag == "link" and attrs.get("rel") in ("canonical",)):
                self.links.append(attrs[key])


def _parse(path: Path) -> _Links:
    parser = _Links()
    parser.feed(path.read_text(encoding="utf-8"))
    return parser


def _target(site: Path, page: Path, link: str) -> tuple[Path, str] | None:
    """The file and fragment an internal link names (None for another site's address or data: URL)."""
    parts = urlsplit(link)
    if parts.scheme or parts.netloc:
        return None
    path = page if not parts.path else (page.parent / unquote(parts.path)).resolve()
    if path.is_dir():
        path = path / "index.html"
    return path, unquote(parts.fragment)


def _unresolved(site: Path) -> list[str]:
    """Every internal link of the built site that names no file, or an anchor its page lacks.

    404.html is left out: a server sends it for any missing address, so its links start at the
    site's root ("/assets/..."), which is not the file system's."""
    pages = {p.resolve(): _parse(p) for p in site.rglob("*.html")}
    bad = []
    for page, parsed in pages.items():
        if page.name == "404.html":
            continue
        for link in parsed.links:
            target = _target(site, page, link)
            if target is None:
                continue
            path, fragment = target
            where = f"{page.relative_to(site)}: {link}"
            if not path.is_file() or not path.is_relative_to(site.resolve()):
                bad.append(where)
            elif fragment and path in pages and fragment not in pages[path].ids and not fragment.startswith("__"):
                bad.append(where + " (no such anchor)")
    return bad


def _chromium(args: list[str], tmp_path: Path) -> subprocess.CompletedProcess:
    assert CHROMIUM.exists(), f"{CHROMIUM} is missing: the site test opens the built site in it. Install it: {INSTALL_CHROMIUM}"
    flags = ["--headless", "--no-sandbox", "--disable-gpu", "--disable-quic", "--no-first-run",
             "--disable-background-networking", "--disable-component-update", "--disable-sync",
             f"--user-data-dir={tmp_path / 'chromium-profile'}", "--window-size=1280,900"]  # fmt: skip
    run = subprocess.run([CHROMIUM, *flags, *args], capture_output=True, text=True, timeout=120)
    assert run.returncode == 0, run.stderr[-3000:]
    return run


@pytest.fixture(scope="module")
def site(tmp_path_factory) -> Path:
    """The site built with ``mkdocs build --strict`` into a temporary folder; its log has no warning."""
    try:
        import mkdocs  # noqa: F401
    except ImportError:
        pytest.fail("mkdocs is not installed: pip install -e '.[docs]' (make docs installs it)")
    out = tmp_path_factory.mktemp("docs") / "site"
    env = {**os.environ, "NO_MKDOCS_2_WARNING": "1"}
    build = subprocess.run([sys.executable, "-m", "mkdocs", "build", "--strict", "-f", ROOT / "mkdocs.yml", "-d", out],
                           cwd=ROOT, env=env, capture_output=True, text=True, timeout=600)  # fmt: skip
    log = build.stdout + build.stderr
    assert build.returncode == 0, log[-5000:]
    assert not re.findall(r"^(?:WARNING|ERROR)\b.*", log, flags=re.M), log
    return out


@pytest.mark.slow
def test_the_site_holds_the_guides_the_notebooks_and_every_public_name(site):
    for guide in sorted((ROOT / "docs").glob("*.md")):
        assert (site / guide.stem / "index.html").is_file() or guide.stem == "index", guide.name
    for name in NOTEBOOKS:
        page = (site / "notebooks" / name / "index.html").read_text(encoding="utf-8")
        assert "jp-OutputArea" in page, f"{name}: no stored output rendered"
    ids = set().union(*(_parse(p).ids for p in (site / "api").rglob("index.html")))
    assert sorted(n for n in _public_names() if f"ctfit.{n}" not in ids) == []
    api = "".join(p.read_text(encoding="utf-8") for p in (site / "api").rglob("index.html"))
    assert not re.search(r":(func|class|meth|mod|data|attr):", api), "a Sphinx role left as text"
    assert api.count('href="#ctfit.') + api.count('/#ctfit.') > 50  # roles became cross-references
    index = (site / "index.html").read_text(encoding="utf-8")
    assert "make docs" in index and "Set up on a fresh machine" in index  # the README
    # its names of guides and notebooks link to their pages, in the guides and docstrings too
    assert '<a href="fitting/"><code>docs/fitting.md</code></a>' in index
    assert '<a href="notebooks/measured_data/"><code>notebooks/measured_data.ipynb</code></a>' in index
    assert '<a href="../../export/"><code>docs/export.md</code></a>' in (site / "api" / "export" / "index.html").read_text(encoding="utf-8")


@pytest.mark.slow
def test_every_internal_link_and_asset_resolves(site):
    assert _unresolved(site) == []


@pytest.mark.slow
def test_the_front_page_renders_in_headless_chromium(site, tmp_path):
    url = (site / "index.html").as_uri()
    dom = _chromium(["--dump-dom", url], tmp_path).stdout
    assert re.search(r"<title>\s*ctfit\s*</title>", dom)
    assert 'class="md-nav' in dom and "Guides" in dom and "Notebooks" in dom
    hrefs = set(re.findall(r'href="([^"]+)"', dom))
    for page in ("api/", "api/fitting/", "api/model/", "notebooks/quickstart/", "fitting/"):
        assert page in hrefs, page
    page = site.resolve() / "index.html"
    assert [h for h in hrefs if (t := _target(site, page, h)) and not t[0].is_file()] == []
    png = tmp_path / "front.png"
    _chromium([f"--screenshot={png}", url], tmp_path)
    pixels = np.asarray(Image.open(png).convert("RGB"))
    assert pixels.shape[:2] == (900, 1280)
    assert (pixels < 200).any(axis=-1).mean() > 0.02, "the screenshot is (nearly) blank"
    assert len(np.unique(pixels.reshape(-1, 3), axis=0)) > 50
