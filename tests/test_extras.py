"""A small core and three extras (issue 24): the core fits without any extra installed, and a
feature whose extra is missing stops before any work with one line naming it."""

import subprocess
import sys
import textwrap

import pytest

from ctfit._runtime import extras

from conftest import ROOT
from test_cli import run

MISSING = "ctfit_no_such_module"
MATERIAL = ROOT / "configs" / "copper-vase.toml"


@pytest.fixture(scope="module")
def measured(tmp_path_factory):
    """A simulated measurement and a fit of it, alone in a folder."""
    d = tmp_path_factory.mktemp("extras")
    csv, fit = d / "cu.csv", d / "cu.fit.json"
    assert run("simulate", MATERIAL, "-o", csv, "--samples", 200, "--seed", 1, "--noise", 0.01, "--wavelengths", "400:700:100").exit_code == 0
    assert run("fit", csv, "--lobes", 1, "--no-diffuse", "-o", fit).exit_code == 0
    return d, csv, fit


def test_need_names_the_extra_and_the_pip_command(monkeypatch):
    monkeypatch.setitem(extras.EXTRAS, "plots", ("matplotlib", MISSING, "PIL"))
    extras.need("posterior", "a chain")  # installed here: nothing happens
    with pytest.raises(extras.MissingExtraError) as e:
        extras.need("plots", "a picture")
    assert str(e.value) == f"a picture needs {MISSING} (not installed): pip install 'ctfit[plots]'"
    assert isinstance(e.value, ImportError)


@pytest.mark.parametrize(
    "extra, args, feature",
    [
        ("cluster", ("fit", "{d}", "--workers", 2, "-o", "{d}/fits"), "--workers"),
        ("plots", ("fit", "{csv}", "--plot", "{d}/p.png"), "--plot"),
        ("posterior", ("fit", "{csv}", "--sample"), "--sample"),
        ("posterior", ("sample", "{fit}", "{csv}"), "ctfit sample"),
        ("plots", ("render", MATERIAL, "-o", "{d}/r.png"), "ctfit render"),
    ],
)
def test_a_missing_extra_stops_the_command_with_one_line_before_any_work(measured, monkeypatch, extra, args, feature):
    d, csv, fit = measured
    monkeypatch.setitem(extras.EXTRAS, extra, (MISSING,))
    before = sorted(p.name for p in d.iterdir())
    r = run(*(str(a).format(d=d, csv=csv, fit=fit) for a in args))
    assert r.exit_code == 2
    assert r.output.strip().splitlines() == [f"error: {feature} needs {MISSING} (not installed): pip install 'ctfit[{extra}]'"]
    assert sorted(p.name for p in d.iterdir()) == before  # nothing written


def test_the_core_fits_evaluates_and_colours_without_any_extra(measured, tmp_path):
    """In a process where no extra can be imported (each module of each extra is None in
    sys.modules, which is what an import of an absent package meets): fit, eval, color,
    simulate run; sample says which extra it needs."""
    d, csv, fit = measured
    blocked = sorted({m for mods in extras.EXTRAS.values() for m in mods})
    script = textwrap.dedent(f"""
        import sys
        for name in {blocked!r}:
            sys.modules[name] = None  # import raises ImportError; importlib.util.find_spec gives None
        from ctfit.cli import main
        sys.argv = ["ctfit", *sys.argv[1:]]
        try:
            main()
        except SystemExit as e:
            sys.exit(e.code)
    """)
    commands = [
        ("fit", csv, "-o", tmp_path / "f.json"),
        ("eval", tmp_path / "f.json", csv, "-o", tmp_path / "m.csv"),
        ("color", MATERIAL),
        ("simulate", MATERIAL, "-o", tmp_path / "s.csv", "--samples", 50, "--wavelengths", "500:600:100"),
    ]
    for args in commands:
        r = subprocess.run([sys.executable, "-c", script, *map(str, args)], capture_output=True, text=True, timeout=600)
        assert r.returncode == 0, (args, r.stderr)
    r = subprocess.run([sys.executable, "-c", script, "sample", str(fit), str(csv)], capture_output=True, text=True, timeout=600)
    assert r.returncode == 2 and r.stderr.strip() == "error: ctfit sample needs arviz, h5py, h5netcdf (not installed): pip install 'ctfit[posterior]'"


def test_the_extras_are_those_pyproject_declares():
    import re
    import tomllib

    declared = tomllib.loads((ROOT / "pyproject.toml").read_text())["project"]["optional-dependencies"]
    for extra, modules in extras.EXTRAS.items():
        packages = {re.split(r"[<>=!~ ]", p)[0].lower() for p in declared[extra]}
        assert packages == {{"PIL": "pillow"}.get(m, m) for m in modules}, extra
    assert declared["all"] == ["ctfit[plots,posterior,cluster]"] and "ctfit[all]" in declared["test"]
    core = {re.split(r"[<>=!~ ]", p)[0].lower() for p in tomllib.loads((ROOT / "pyproject.toml").read_text())["project"]["dependencies"]}
    assert not core & {m.lower() for mods in extras.EXTRAS.values() for m in mods} and "pillow" not in core
