"""Messages of the ctfit command: every option they name exists, library errors name the CLI
option, flags show as flags in --help."""

import ast
import re

import hypothesis.strategies as st
import pytest
import typer.main
from hypothesis import given, settings
from typer.testing import CliRunner

from ctfit._cli.messages import cli_message as _cli_message
from ctfit.cli import app

from conftest import ROOT

OPTION = re.compile(r"(?<![\w-])--[a-z][a-z0-9]*(?:-[a-z0-9]+)*")


def cli_options() -> set[str]:
    """Every option the typer app defines, over all its commands (and --help)."""
    group = typer.main.get_command(app)
    commands = [group, *group.commands.values()]
    return {o for c in commands for p in c.params for o in (*p.opts, *p.secondary_opts)} | {"--help"}


def named_options() -> dict[str, list[str]]:
    """Every --option token in a string literal of the ctfit package: {option: [file:line, …]}."""
    found = {}
    for path in sorted((ROOT / "ctfit").rglob("*.py")):
        for node in ast.walk(ast.parse(path.read_text(encoding="utf-8"))):
            if isinstance(node, ast.Constant) and isinstance(node.value, str):
                for option in OPTION.findall(node.value):
                    found.setdefault(option, []).append(f"{path.relative_to(ROOT)}:{node.lineno}")
    return found


def test_the_collector_sees_messages_and_options():
    named, defined = named_options(), cli_options()
    assert {"--param-out", "--max-steps", "--lobes", "--resume"} <= set(named)
    assert {"--starts", "--max-steps", "--quiet", "-q", "--no-diffuse", "--samples"} <= defined


def test_every_option_named_in_a_message_exists():
    defined = cli_options()
    missing = {option: where for option, where in named_options().items() if option not in defined}
    assert not missing, f"options named in messages but not defined by the ctfit command: {missing}"


@pytest.mark.parametrize(
    "library, cli",
    [
        ("x.dat: no #PARAM_OUT line: the unit of the values is unknown. Add one (…) or pass param_out=...", "or pass --param-out"),
        ("x.dat:7: #PARAM_OUT INV_STERADIAN contradicts param_out='A'", "contradicts --param-out='A'"),
        ("max_theta must be in (0, 90) degrees, got 90.0", "--max-theta must be in (0, 90) degrees, got 90.0"),
        ("walkers must be even and ≥ 2·ndim = 14, got 8", "--walkers must be even and ≥ 2·ndim = 14, got 8"),
        ("run.h5: the stored run already has 30 steps, more than steps=20", "run.h5: the stored run already has 30 steps, more than --steps=20"),
        ("run.h5: the stored run was sampled for other data; pass resume=False", "run.h5: the stored run was sampled for other data; leave out --resume"),
        ('undamped steps: fit with the damped solver (solver="lm", the default) or from more starts (starts=3)',
         "undamped steps: fit with the damped solver (--solver lm, the default) or from more starts (--starts 3)"),
    ],
)
def test_library_argument_names_become_options(library, cli):
    assert cli in _cli_message(library)


def test_a_library_error_reaches_the_user_with_the_option_name(tmp_path):
    r = CliRunner().invoke(app, ["simulate", str(ROOT / "configs" / "gold.toml"), "-o", str(tmp_path / "x.csv"), "--max-theta", "90"])
    assert r.exit_code == 2
    assert r.stderr.strip().startswith("error: --max-theta must be in") and "max_theta" not in r.stderr


@pytest.mark.parametrize("command", [[], ["eval"], ["simulate"], ["fit"], ["sample"], ["render"], ["color"]])
def test_flags_show_as_flags_in_help(command):
    r = CliRunner().invoke(app, [*command, "--help"])
    assert r.exit_code == 0, r.output
    assert "--help" in r.stdout
    assert not re.search(r"<bool>|BOOLEAN", r.stdout, flags=re.I), r.stdout


@pytest.mark.parametrize("command", ["eval", "fit", "sample"])
def test_param_out_help_names_every_unit_it_takes(command):
    """RGB_COLOR was taken (a #DIM 1 3 file without #PARAM_OUT) but not named in the help."""
    from ctfit._cli.inputs import PARAM_OUT_UNITS

    text = " ".join(CliRunner().invoke(app, [command, "--help"], terminal_width=200).stdout.split())
    assert all(unit in text.split("--param-out", 1)[1] for unit in PARAM_OUT_UNITS), text


def test_fit_help_lists_each_flag_without_a_value():
    text = CliRunner().invoke(app, ["fit", "--help"]).stdout
    for flag in ("--json", "--float32", "--sample", "--resume", "--quiet", "--no-diffuse"):
        line = next(line for line in text.splitlines() if line.strip().startswith(flag) or f", {flag}" in line)
        assert "<" not in line.split(flag, 1)[1].split("  ")[0], line


def test_colour_is_spelled_one_way_and_the_other_is_an_alias(tmp_path):
    """``ctfit color --colorspace`` is the spelling; ``ctfit colour`` and ``--colourspace`` give the same."""
    import json

    material = ROOT / "configs" / "copper-vase.toml"
    runner = CliRunner()
    outs = [runner.invoke(app, [cmd, str(material), opt, "Display P3", "--json"]) for cmd, opt in
            (("color", "--colorspace"), ("colour", "--colourspace"), ("color", "--colourspace"))]
    assert all(o.exit_code == 0 for o in outs), [o.output for o in outs]
    docs = [json.loads(o.output) for o in outs]
    assert docs[0] == docs[1] == docs[2] and "Display P3" in json.dumps(docs[0])
    listed = re.findall(r"^\s+(\w+)\s", runner.invoke(app, ["--help"]).output.split("Commands")[-1], re.M)
    assert "color" in listed and "colour" not in listed  # the alias stays hidden


def test_the_library_names_its_own_arguments_and_the_command_its_options():
    """No message of the library names a command-line option (issue 24): it says ``max_steps=``,
    ``loss=``, ``structure=``, …, and the command translates what it shows."""
    import ast
    import re

    from ctfit._cli.messages import cli_message

    from conftest import ROOT

    flag = re.compile(r"(?<![\w-])--[a-z][a-z0-9-]*")
    hits = []
    for path in sorted((ROOT / "ctfit").rglob("*.py")):
        if "_cli" in path.parts or path.name == "cli.py":
            continue
        tree = ast.parse(path.read_text())
        docstrings = {
            id(node.body[0].value)
            for node in ast.walk(tree)
            if isinstance(node, (ast.Module, ast.ClassDef, ast.FunctionDef)) and node.body
            and isinstance(node.body[0], ast.Expr) and isinstance(node.body[0].value, ast.Constant)
        }
        for node in ast.walk(tree):
            text = node.value if isinstance(node, ast.Constant) and isinstance(node.value, str) else ""
            if id(node) not in docstrings and flag.search(text) and not re.fullmatch(r"--[a-z-]+", text):  # an option given as a value
                hits.append(f"{path.relative_to(ROOT)}:{node.lineno}: {text[:80]!r}")
    assert hits == []
    shown = {
        "not a minimum (more max_steps=, or another start)": "not a minimum (more --max-steps, or another start)",
        "try other lobes (structure=), starting values (start=) or another loss=": "try other lobes (--lobes), starting values (--material) or another --loss",
        "fit in float64 (dtype=float64), from another start": "fit in float64 (without --float32), from another start",
        "start again (overwrite=True)": "start again (--overwrite)",
        "sigma_noise = 0.1, steps: 30, loss: log": "sigma_noise = 0.1, steps: 30, loss: log",  # a table's values stay as they are
    }
    assert {k: cli_message(k) for k in shown} == shown


_PIECES = ["param_out", "max_steps", "steps", "loss", "seed", "=", " = ", "=...", " must ", "must", "(structure=)", "(start=)",
           "resume=False", "overwrite=True", "(dtype=float64)", " ", "\n", ",", ")", "x", "-", "m = 0.2 ± 0.01", "steps: 7"]


@settings(max_examples=400, deadline=None)
@given(st.lists(st.sampled_from(_PIECES), max_size=12))
def test_a_text_passed_over_quickly_has_nothing_to_turn(pieces):
    """The quick look (``=`` only after a space, no ``must``) passes over a text only where the
    phrases and patterns would change nothing; otherwise they run as ever."""
    from ctfit._cli.messages import _nothing_to_turn, _turned

    text = "".join(pieces)
    assert _cli_message(text) == _turned(text)
    if _nothing_to_turn(text):
        assert _turned(text) == text


def test_a_fit_table_is_passed_over_and_a_warning_in_it_is_turned():
    import numpy as np

    import ctfit
    from ctfit._cli.messages import _nothing_to_turn

    gold = ctfit.Material(ctfit.Structure(lobes=1, diffuse=None), ctfit.Params(m=np.array([0.2]), w=np.ones(1), f0=np.array([0.4, 0.9])),
                          wavelength_nm=np.array([450.0, 650.0]))
    table = ctfit.format_fit_table(ctfit.fit(ctfit.simulate(gold, n_pairs=300, noise=0.01, seed=1), gold.structure), "gold")
    assert _nothing_to_turn(table)
    assert _cli_message(table + "\n  warning: not a minimum (more max_steps=, or another start)").endswith("(more --max-steps, or another start)")


@settings(max_examples=200, deadline=None)
@given(st.dictionaries(st.text(max_size=5), st.text(max_size=8) | st.integers(-10**6, 10**6) | st.lists(st.text(max_size=3), max_size=3), max_size=5))
def test_fit_json_on_stdout_is_ascii_and_the_same_document(doc):
    """``--json`` prints the file's text with every character past ASCII escaped as ``json.dumps``
    escapes it: the same document, the same text as ``json.dumps(doc, indent=2)`` where the numbers
    are written alike (here, integers and strings)."""
    import json

    from ctfit._cli.fit_command import ascii_json
    from ctfit._io import material_json

    out = ascii_json(material_json(doc)[:-1])
    assert out.isascii() and "\x7f" not in out
    assert out == json.dumps(doc, indent=2)
    assert json.loads(out) == doc
