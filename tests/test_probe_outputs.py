"""A hostile user's outputs (issue 20): no command loses or corrupts a file — outputs spelled
through missing folders and ``..``, a closed stdout, links in output folders, Ctrl-C and SIGKILL
during a write, folder outputs, long names, plain messages for missing inputs."""

from __future__ import annotations

import json
import os
import subprocess
import sys
import time
from pathlib import Path

import pytest
from test_outputs import no_work  # noqa: F401 — the fixture: a command that starts work before checking its outputs fails
from typer.testing import CliRunner

from ctfit._io import files as _fileio, output_paths
from ctfit._io.output_paths import OutputError, check_output
from ctfit.cli import app

from conftest import ROOT

MATERIAL = ROOT / "configs" / "copper-vase.toml"
SMALL = ("--samples", 30, "--wavelengths", "450:650:100")
runner = CliRunner()


def run(*args):
    return runner.invoke(app, [str(a) for a in args])


def _ctfit(*args):
    return [sys.executable, "-m", "ctfit.cli", *map(str, args)]


def _env(tmp_path):
    env = {k: v for k, v in os.environ.items() if k != "HOME"}
    return dict(env, HOME=str(tmp_path / "home"), MPLBACKEND="Agg", JAX_PLATFORMS="cpu", CTFIT_PROGRESS="0")


@pytest.fixture
def inputs(tmp_path, monkeypatch):
    """data.csv and m.toml in the current folder (the probe's relative spellings)."""
    monkeypatch.chdir(tmp_path)
    Path("data.csv").write_text("theta_i,phi_i,theta_o,phi_o,wavelength_nm,brdf\n10,0,10,180,500,1\n")
    Path("m.toml").write_bytes(MATERIAL.read_bytes())
    return Path("data.csv"), Path("m.toml")


# --- 1. an output spelled through a missing folder and '..' ------------------------------------


def test_dotdot_after_a_missing_folder_is_the_input(inputs):
    data, _ = inputs
    for spelling in ("nothere/../data.csv", "a/b/../../data.csv", os.path.abspath("nothere/../data.csv")):
        with pytest.raises(OutputError, match="is the input data.csv"):
            check_output(spelling, [data])
        assert output_paths.same_file(spelling, data)
    assert not Path("nothere").exists() and not Path("a").exists()  # refused before any folder is made


def test_every_command_refuses_the_input_spelled_through_a_missing_folder(inputs, no_work):
    data, mat = inputs
    before = data.read_bytes(), mat.read_bytes()
    Path("fit.json").write_text("{}")
    for args, victim in [
        (("fit", data, "-o", "n1/../data.csv"), data),
        (("fit", data, "-o", "f.json", "--plot", "n1/../data.csv"), data),
        (("eval", mat, data, "-o", "n2/../data.csv"), data),
        (("eval", mat, data, "-o", "n2/../m.toml"), mat),
        (("simulate", mat, "-o", "n3/../m.toml"), mat),
        (("render", mat, "-o", "n4/../m.toml"), mat),
        (("sample", "fit.json", data, "--backend", "n5/../data.csv", "--overwrite"), data),
        (("sample", "fit.json", data, "-o", "x.json", "--idata", "n6/../data.csv"), data),
        (("sample", mat, data, "-o", "n7/../data.csv"), data),
    ]:
        r = run(*args)
        assert r.exit_code == 2, (args, r.output)
        assert r.output.startswith("error: ") and f"is the input {victim}" in r.output, (args, r.output)
    assert (data.read_bytes(), mat.read_bytes()) == before
    assert not [p for p in Path().iterdir() if p.name.startswith("n")]


def test_texel_maps_refuse_the_input_as_output(tmp_path, no_work):
    store = tmp_path / "texels.zarr"
    store.mkdir()
    for out, said in ((store, "is the input"), (tmp_path / "x" / ".." / "texels.zarr", "is the input"), (store / "maps.zarr", "is inside the input")):
        r = run("fit", store, "-o", out)
        assert r.exit_code == 2 and r.output.startswith("error: -o ") and said in r.output, r.output


# --- 2. a closed stdout costs no result --------------------------------------------------------


@pytest.mark.slow
def test_a_closed_stdout_costs_no_result(tmp_path):
    names = ["a.csv", "b.csv", "c.csv"]
    for i, name in enumerate(names):
        assert run("simulate", MATERIAL, "-o", tmp_path / name, *SMALL, "--seed", i).exit_code == 0
    out = tmp_path / "out"
    named = ("--family", "metal", "--lobes", 1, "--diffuse", "F0/pi")  # one structure: a cold process compiles one, not the choice's
    proc = subprocess.Popen(_ctfit("fit", *(tmp_path / n for n in names), "-o", out, "--starts", 1, *named), env=_env(tmp_path),
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    proc.stdout.close()  # `| head -0`: the reader is gone before the first table
    with proc.stderr:
        err = proc.stderr.read()
    assert proc.wait(timeout=300) == 0, err
    assert "Broken pipe" not in err and "Traceback" not in err, err
    assert sorted(p.name for p in out.iterdir()) == ["a.fit.json", "b.fit.json", "c.fit.json", "summary.json"]
    assert json.loads((out / "summary.json").read_text())["converged"] == 3


@pytest.mark.parametrize("to", ["gltf", "mitsuba"])
def test_an_export_to_stdout_is_the_file_alone(tmp_path, to):
    """``export -o /dev/stdout``: the exported document alone on standard output, its error line
    on standard error (the line went into the document: invalid JSON, an XML Mitsuba refused)."""
    proc = subprocess.run(_ctfit("export", ROOT / "configs" / "rubber.toml", "--to", to, "-o", "/dev/stdout"), env=_env(tmp_path),
                          capture_output=True, text=True, timeout=300)
    assert proc.returncode == 0, proc.stderr
    assert proc.stderr.startswith(f"{to}: ") and len(proc.stderr.splitlines()) == 1, proc.stderr
    if to == "gltf":
        assert json.loads(proc.stdout)["asset"]["version"] == "2.0"
    else:
        assert proc.stdout.startswith("<!-- ctfit export") and proc.stdout.rstrip().endswith("</bsdf>") and f"{to}: " not in proc.stdout.splitlines()[0]


def test_a_closed_pipe_as_output_ends_the_write_quietly(tmp_path):
    r, w = os.pipe()
    os.close(r)
    _fileio.atomic_write(f"/proc/self/fd/{w}", ["x" * 100000] * 10)  # no BrokenPipeError
    os.close(w)


# --- 3. links in an output folder --------------------------------------------------------------


def _outside_links(tmp_path):
    outside = tmp_path / "outside"
    outside.mkdir()
    (outside / "important.txt").write_text("keep me")
    out = tmp_path / "sub" / "out"
    out.mkdir(parents=True)
    return out, outside / "important.txt"


@pytest.mark.parametrize("name", ["a.fit.json", "summary.json"])
def test_a_folder_run_refuses_a_link_it_would_write_through(tmp_path, no_work, name):
    out, important = _outside_links(tmp_path)
    (out / name).symlink_to(Path("..") / ".." / "outside" / "important.txt")
    for n in ("a.csv", "b.csv"):
        (tmp_path / n).write_text("x\n")
    r = run("fit", tmp_path / "a.csv", tmp_path / "b.csv", "-o", out)
    assert r.exit_code == 2, r.output
    assert r.output.startswith(f"error: -o {out}: {out / name} is a symbolic link (to ../../outside/important.txt)"), r.output
    assert important.read_text() == "keep me" and (out / name).is_symlink()


def test_writes_into_an_output_folder_replace_a_link_not_its_target(tmp_path):
    out, important = _outside_links(tmp_path)
    (out / "m.png").symlink_to(important)
    _fileio.replace_links_in(out)
    _fileio.atomic_write(out / "m.png", [b"new"])
    assert not (out / "m.png").is_symlink() and (out / "m.png").read_bytes() == b"new"
    assert important.read_text() == "keep me"
    link = tmp_path / "named.txt"  # a link the user names as the output is written through, as before
    link.symlink_to(important)
    _fileio.atomic_write(link, ["new"])
    assert link.is_symlink() and important.read_text() == "new"


# --- 4, 5, 19. the temporary file: Ctrl-C, SIGKILL, long names --------------------------------

_WRITE = """
import os, signal, sys
from ctfit._io import files
from ctfit._cli.interrupt import install
install(lambda: "interrupted")
path, where = sys.argv[1], sys.argv[2]
SIGNAL = signal.SIGTERM if len(sys.argv) > 3 else signal.SIGINT
def chunks():
    yield "new, "
    if where == "writing":
        os.kill(os.getpid(), SIGNAL)
    yield "and more"
if where == "renaming":
    rename = os.replace
    def replace(a, b):
        os.kill(os.getpid(), signal.SIGINT)
        rename(a, b)
    os.replace = replace
files.atomic_write(path, chunks())
print("not reached")
"""


@pytest.mark.parametrize("where", ["writing", "renaming"])
def test_ctrl_c_during_a_write_says_what_became_of_the_file(tmp_path, where):
    out = tmp_path / "out.csv"
    out.write_text("old")
    r = subprocess.run([sys.executable, "-c", _WRITE, out, where], capture_output=True, text=True, timeout=120)
    assert r.returncode == 130 and r.stdout == ""
    if where == "writing":
        assert r.stderr == f"interrupted; {out} was not written (its old content is kept)\n"
        assert out.read_text() == "old"
    else:
        assert r.stderr == f"interrupted; {out} was written in full\n"
        assert out.read_text() == "new, and more"
    assert sorted(p.name for p in tmp_path.iterdir()) == ["out.csv"]


def test_sigterm_during_a_write_is_handled_as_ctrl_c_is(tmp_path):
    """``kill`` (SIGTERM) during a write: the temporary file removed, the old file kept, one line,
    status 143 (it left a temporary file of the whole write, and said nothing)."""
    out = tmp_path / "out.csv"
    out.write_text("old")
    r = subprocess.run([sys.executable, "-c", _WRITE, out, "writing", "term"], capture_output=True, text=True, timeout=120)
    assert r.returncode == 143 and r.stdout == ""
    assert r.stderr == f"terminated; {out} was not written (its old content is kept)\n"
    assert out.read_text() == "old" and sorted(p.name for p in tmp_path.iterdir()) == ["out.csv"]


def test_stale_temporaries_are_removed_by_the_next_write_into_their_folder(tmp_path):
    gone = subprocess.Popen([sys.executable, "-c", "pass"])
    gone.wait()  # a process that has ended: its temporaries are stale
    alive = subprocess.Popen([sys.executable, "-c", "import time; time.sleep(60)"])
    try:
        time.sleep(0.2)
        stale = tmp_path / f".ctfit-{gone.pid}-0123abcd.tmp"
        reused = tmp_path / f".ctfit-{alive.pid}-89abcdef.tmp"  # older than the process that has that PID now
        running = tmp_path / f".ctfit-{alive.pid}-01234567.tmp"  # the live process's own write
        other = tmp_path / f".data.csv.{gone.pid}.0123abcd.tmp"  # not ctfit's name: left alone
        for p in (stale, reused, running, other):
            p.write_bytes(b"partial")
        os.utime(reused, (1e9, 1e9))
        seen = []

        def chunks():
            seen.extend(p.name for p in tmp_path.iterdir() if _fileio.TEMPORARY.match(p.name))
            yield b"whole"

        _fileio.atomic_write(tmp_path / "result.json", chunks())
    finally:
        alive.kill()
        alive.wait()
    assert sorted(p.name for p in tmp_path.iterdir()) == sorted([running.name, other.name, "result.json"])
    mine = [n for n in seen if n != running.name]
    assert len(mine) == 1 and mine[0].startswith(f".ctfit-{os.getpid()}-")  # the write's own, recognisable temporary


def test_any_valid_name_can_be_written_and_an_invalid_one_is_refused_first(tmp_path, no_work):
    long = tmp_path / ("a" * 246 + ".csv")  # 250 bytes: its old temporary name had 270
    _fileio.atomic_write(long, ["x\n"])
    assert long.read_text() == "x\n" and sorted(tmp_path.iterdir()) == [long]
    too_long = tmp_path / ("b" * 252 + ".csv")
    with pytest.raises(OutputError, match="the file name is 256 bytes long; the file system takes at most 255"):
        check_output(too_long)
    data = tmp_path / ("c" * 248 + ".csv")  # its result c….fit.json would have 257 bytes
    data.write_text("x\n")
    (tmp_path / "d.csv").write_text("x\n")
    r = run("fit", data, tmp_path / "d.csv", "-o", tmp_path / "out")
    assert r.exit_code == 2 and "the file name is 257 bytes long" in r.output, r.output


# --- 14. folder outputs -------------------------------------------------------------------------


@pytest.mark.slow
def test_a_folder_input_or_a_folder_output_gives_a_folder_with_a_summary(tmp_path):
    folder = tmp_path / "in"
    folder.mkdir()
    assert run("simulate", MATERIAL, "-o", folder / "one.csv", *SMALL).exit_code == 0
    existing = tmp_path / "existing"
    existing.mkdir()
    for data, out in ((folder, f"{tmp_path / 'out'}/"), (folder, tmp_path / "out2"), (folder / "one.csv", existing),
                      (folder / "one.csv", f"{tmp_path / 'new'}/")):
        r = run("fit", data, "-o", out, "--starts", 1)
        assert r.exit_code == 0, r.output
        out = Path(out)
        assert out.is_dir() and sorted(p.name for p in out.iterdir()) == ["one.fit.json", "summary.json"], (data, out)
        summary = json.loads((out / "summary.json").read_text())
        assert summary["results"][0]["result"] == str(out / "one.fit.json") and summary["results"][0]["input_sha256"]


# --- 20. messages ------------------------------------------------------------------------------


def test_missing_and_folder_inputs_are_named_in_plain_words(tmp_path):
    missing = tmp_path / "missing.csv"
    for args, said in [
        (("eval", MATERIAL, missing, "-o", tmp_path / "x.csv"), f"error: {missing}: no such file"),
        (("eval", MATERIAL, tmp_path, "-o", tmp_path / "x.csv"), f"error: {tmp_path}: not a regular file but a folder; ctfit reads files only"),
        (("sample", MATERIAL, missing, "-o", tmp_path / "x.json"), f"error: {missing}: no such file"),
        (("sample", MATERIAL, tmp_path, "-o", tmp_path / "x.json"), f"error: {tmp_path}: not a regular file but a folder; ctfit reads files only"),
        (("render", MATERIAL, "-o", tmp_path / "x.png", "--compare", missing), f"error: {missing}: no such file"),
        (("render", MATERIAL, "-o", tmp_path / "x.png", "--compare", tmp_path), f"error: {tmp_path}: not a regular file but a folder; ctfit reads files only"),
    ]:
        r = run(*args)
        assert (r.exit_code, r.output) == (2, said + "\n"), args


def test_a_plot_format_matplotlib_cannot_write_is_refused_before_the_fit(tmp_path, no_work):
    (tmp_path / "d.csv").write_text("x\n")
    r = run("fit", tmp_path / "d.csv", "--plot", tmp_path / "x.txt")
    assert r.exit_code == 2 and r.output.startswith(f"error: --plot {tmp_path / 'x.txt'}: matplotlib writes no .txt files"), r.output
    assert ".png" in r.output and ".pdf" in r.output and ".svg" in r.output


_CLUSTER = """
import os, signal, sys
from ctfit._cli.interrupt import install
from ctfit._runtime import dask_client
install(lambda: "interrupted")
with dask_client(workers=1) as client:
    client.submit(sum, [1, 2]).result()
    os.kill(os.getpid(), signal.SIGINT)
    import time; time.sleep(60)
"""


@pytest.mark.slow
def test_ctrl_c_with_a_local_cluster_leaves_no_semaphore_behind(tmp_path):
    r = subprocess.run([sys.executable, "-c", _CLUSTER], capture_output=True, text=True, timeout=180, env=_env(tmp_path), cwd=tmp_path)
    assert (r.returncode, r.stderr) == (130, "interrupted\n")


# --- beyond the list ---------------------------------------------------------------------------


def test_a_read_only_folder_is_refused_even_for_root(tmp_path, no_work):
    folder = tmp_path / "kept"
    folder.mkdir()
    folder.chmod(0o555)
    try:
        r = run("simulate", MATERIAL, "-o", folder / "x.csv")
        assert r.exit_code == 2 and f"the folder {folder} is not writable (mode dr-xr-xr-x)" in r.output, r.output
    finally:
        folder.chmod(0o755)
    assert list(folder.iterdir()) == []


def test_a_link_that_leads_to_itself_is_refused(tmp_path, no_work):
    loop = tmp_path / "loop"
    loop.symlink_to("loop")
    r = run("simulate", MATERIAL, "-o", loop)
    assert r.exit_code == 2 and "is a symbolic link that leads to itself" in r.output, r.output
    assert loop.is_symlink()



def test_a_trailing_slash_names_a_folder_where_a_file_is_wanted(tmp_path, no_work):
    (tmp_path / "d.csv").write_text("x\n")
    (tmp_path / "f.json").write_text("{}")
    for args, option in [
        (("simulate", MATERIAL, "-o", f"{tmp_path / 'new'}/"), "-o"),
        (("eval", MATERIAL, tmp_path / "d.csv", "-o", f"{tmp_path / 'new'}/"), "-o"),
        (("render", MATERIAL, "-o", f"{tmp_path / 'new'}/"), "-o"),
        (("export", MATERIAL, "--to", "gltf", "-o", f"{tmp_path / 'new'}/"), "-o"),  # wrote a file named new
        (("sample", tmp_path / "f.json", tmp_path / "d.csv", "--idata", f"{tmp_path / 'new'}/"), "--idata"),
    ]:
        r = run(*args)
        assert (r.exit_code, r.output) == (2, f"error: {option} {tmp_path / 'new'}/: ends with '/', so it names a folder; give a file name\n")
    assert sorted(p.name for p in tmp_path.iterdir()) == ["d.csv", "f.json"]
