"""The ``ctfit`` command: eval, simulate, fit, sample, color, render.

Heavy imports (JAX, colour-science) happen inside the commands, so ``ctfit --version`` is fast.
Errors in the input (bad files, bad options) print one ``error:`` line naming the file, line
and column where known, and exit with status 2; a fit that does not converge exits with 1.
Warnings print as one line ``warning: MESSAGE``; ``fit`` over several files goes on after a
file's error and ends with a summary (docs/fitting.md). Outputs are checked before any work
(``_io/output_paths.py``); Ctrl-C exits with status 130 and one line, ``interrupted`` (``_io/interrupt.py``).
"""

from __future__ import annotations

import json
import re
import sys
from pathlib import Path
from types import SimpleNamespace
from typing import List, Optional

import typer

app = typer.Typer(add_completion=False, no_args_is_help=True, rich_markup_mode=None, help="Fit the Cook–Torrance reflectance model to BRDF samples.")


class UserError(Exception):
    """An error caused by the input, reported without a traceback."""


def _version(value: bool):
    if value:
        from importlib.metadata import PackageNotFoundError, version

        try:
            typer.echo(f"ctfit {version('ctfit')}")
        except PackageNotFoundError:
            typer.echo("ctfit (source tree)")
        raise typer.Exit()


@app.callback()
def _main(version: bool = typer.Option(False, "--version", callback=_version, is_eager=True, help="Print the version and exit.")):
    """ctfit: Cook–Torrance fitting in JAX."""


def _setup_jax(float32: bool = False):
    import jax

    if not float32:
        jax.config.update("jax_enable_x64", True)
    from .._runtime import enable_compilation_cache

    enable_compilation_cache()


def _load_material(path: Path):
    from .._io import load_material

    return load_material(path)


def _read_data(path: Path, param_out: str | None = None):
    """Read a measurement (once); ``--param-out`` serves only an ALTA file without its own #PARAM_OUT line."""
    from .._fitting import read_input

    return read_input(path, param_out)


_PARAM_OUT_HELP = "ALTA files without a #PARAM_OUT line: the unit of their values (INV_STERADIAN or INV_STERADIAN_COSINE_FACTOR)."


def _parse_wavelengths(text: str | None):
    import numpy as np

    if text is None:
        return None
    try:
        if ":" in text:
            parts = [float(x) for x in text.split(":")]
            if len(parts) != 3 or parts[2] <= 0:
                raise ValueError
            return np.arange(parts[0], parts[1] + 0.5 * parts[2], parts[2])
        return np.array([float(x) for x in text.split(",") if x.strip()])
    except ValueError:
        raise UserError(f"--wavelengths: expected START:STOP:STEP or a comma-separated list, got {text!r}") from None


_CLI_PHRASES = {"pass resume=False": "leave out --resume", "resume=False": "leave out --resume", "param_out=...": "--param-out"}
_CLI_NAMES = {  # library argument → the option that sets it, for library messages shown by the CLI
    "param_out": "--param-out",
    "max_steps": "--max-steps",
    "max_theta": "--max-theta",
    "n_pairs": "--samples",
    "noise": "--noise",
    "walkers": "--walkers",
    "steps": "--steps",
    "thin": "--thin",
    "burn": "--burn",
}
_CLI_NAME = re.compile(r"(?<![\w-])(" + "|".join(_CLI_NAMES) + r")(?==|\s+must\b)")


def _cli_message(text: str) -> str:
    """A library message with its Python argument names (``param_out=``) turned into options."""
    for phrase, option in _CLI_PHRASES.items():
        text = text.replace(phrase, option)
    return _CLI_NAME.sub(lambda m: _CLI_NAMES[m[1]], text)


def _show_warning(message, category, filename, lineno, file=None, line=None):
    """``warnings.showwarning`` for the CLI: one ``warning: MESSAGE`` line, no source location."""
    from .._runtime import echo

    echo(f"warning: {_cli_message(str(message))}", err=True)


def _run(fn):
    """Run a command body: warnings as one line each, input errors as one line and exit status 2."""
    import warnings

    with warnings.catch_warnings():
        warnings.showwarning = _show_warning
        try:
            return fn()
        except UserError as e:
            typer.echo(f"error: {e}", err=True)
            raise typer.Exit(2)
        except (ValueError, OSError, KeyError) as e:
            typer.echo(f"error: {_cli_message(str(e))}", err=True)
            raise typer.Exit(2)


@app.command("eval")
def eval_cmd(
    material: Path = typer.Argument(..., help="Material TOML or fit-result JSON."),
    data: Path = typer.Argument(..., help="Measurement CSV (a 'brdf' column is optional and replaced)."),
    output: Path = typer.Option(..., "-o", "--output", help="Output CSV."),
    float32: bool = typer.Option(False, "--float32", help="Evaluate in float32 (default float64)."),
    param_out: Optional[str] = typer.Option(None, "--param-out", help=_PARAM_OUT_HELP),
):
    """The material's BRDF at every row of DATA, written as a measurement CSV."""

    def body():
        from .._io import check_output

        check_output(output, [material, data])
        _setup_jax(float32)
        from .._io import write_csv
        from .._model import evaluate

        mat = _load_material(material)
        meas = _read_data(data, param_out)
        values = evaluate(mat, meas)
        meta = dict(meas.meta)
        meta.update({"evaluated_by": "ctfit eval", "material": str(material)})
        write_csv(meas.replace(brdf=values, sigma=None, meta=meta), output)
        typer.echo(f"wrote {len(values)} samples to {output}", err=True)

    _run(body)


@app.command()
def simulate(
    material: Path = typer.Argument(..., help="Material TOML or fit-result JSON."),
    output: Path = typer.Option(..., "-o", "--output", help="Output CSV."),
    samples: int = typer.Option(2000, "--samples", min=1, help="Direction pairs (each measured in every band)."),
    seed: int = typer.Option(0, "--seed"),
    noise: float = typer.Option(0.0, "--noise", min=0.0, help="Relative Gaussian noise (0.02 = 2 %); adds a sigma column."),
    wavelengths: Optional[str] = typer.Option(None, "--wavelengths", help="START:STOP:STEP or a list, nm (default: the material's within 400–700)."),
    max_theta: float = typer.Option(85.0, "--max-theta", min=0.0, max=90.0, help="Largest polar angle of light and viewer, degrees."),
):
    """Synthetic goniometric measurements of MATERIAL (denser near the mirror direction)."""

    def body():
        from .._io import check_output

        check_output(output, [material])
        _setup_jax()
        from .._io import write_csv
        from .._model import simulate as sim

        mat = _load_material(material)
        meas = sim(mat, samples, wavelength_nm=_parse_wavelengths(wavelengths), noise=noise, seed=seed, max_theta=max_theta)
        meta = dict(meas.meta, material=str(material))
        write_csv(meas.replace(meta=meta), output)
        typer.echo(f"wrote {len(meas)} samples ({samples} direction pairs × {meas.n_bands} bands) to {output}", err=True)

    _run(body)


def _structure_from_options(base, lobes: int, geometry, fresnel, diffuse):
    from .._model import Structure

    fres = {"effective-n": "f0", "conductor": "conductor", None: None}[fresnel]
    if base is not None:
        st = base
        kw = {}
        if geometry:
            kw["geometry"] = geometry
        if fres:
            kw["fresnel"] = fres
        return Structure(**{**st.__dict__, **kw})
    return Structure(lobes=lobes, geometry=geometry or "v-cavity", fresnel=fres or "f0", diffuse=("F0/pi" if diffuse else None))


@app.command()
def fit(
    data: List[Path] = typer.Argument(..., metavar="DATA", help="Measurement files (CSV, ALTA, MERL .binary) or folders of them."),
    output: Optional[Path] = typer.Option(None, "-o", "--output", help="Write the fit-result JSON here (one file: this path; several: a folder)."),
    as_json: bool = typer.Option(False, "--json", help="Print the fit-result JSON to stdout instead of the table."),
    material: Optional[Path] = typer.Option(None, "--material", help="Material file: structure, starting values and (key 'fixed') fixed parameters."),
    lobes: str = typer.Option("1", "--lobes", help="Number of lobes, or 'auto' (1–3, with/without diffuse, by BIC)."),
    geometry: Optional[str] = typer.Option(None, "--geometry", help="v-cavity (default), smith or smith-rational (Smith with the rational G1 of Mitsuba 3)."),
    fresnel: Optional[str] = typer.Option(None, "--fresnel", help="effective-n (default: k = 0, n from F0) or conductor (n, k)."),
    diffuse: bool = typer.Option(True, "--diffuse/--no-diffuse", help="Include a diffuse part R_d = F0/π."),
    loss: str = typer.Option("auto", "--loss", help="auto, absolute, relative, sigma, cosine or log."),
    solver: str = typer.Option("lm", "--solver", help="lm, gauss-newton, dogleg or bfgs."),
    float32: bool = typer.Option(False, "--float32", help="Fit in float32 (default float64)."),
    starts: int = typer.Option(3, "--starts", min=1, help="Seeds from the grid over m, solved at once."),
    max_steps: int = typer.Option(256, "--max-steps", min=1, help="Solver steps per start (more for a fit that stops short of a minimum)."),
    param_out: Optional[str] = typer.Option(None, "--param-out", help=_PARAM_OUT_HELP + " A file's own line wins."),
    plot: Optional[Path] = typer.Option(None, "--plot", help="Write a PNG of data vs fit (one file: this path; several: a folder)."),
    sample_: bool = typer.Option(False, "--sample", help="Also sample the posterior (emcee) and add an 'uncertainty' section."),
    walkers: Optional[int] = typer.Option(None, "--walkers", min=2, help="With --sample: walkers, even (default max(2·ndim + 2, 32))."),
    steps: int = typer.Option(2000, "--steps", min=1, help="With --sample: steps per walker."),
    burn: Optional[int] = typer.Option(None, "--burn", min=0, help="With --sample: steps discarded (fewer than --steps)."),
    thin: int = typer.Option(1, "--thin", min=1, help="With --sample: keep every THIN-th step."),
    seed: int = typer.Option(0, "--seed", help="With --sample: random seed."),
    backend: Optional[Path] = typer.Option(None, "--backend", help="With --sample: HDF5 chain file (several data files: a folder)."),
    resume: bool = typer.Option(False, "--resume", help="With --sample: continue the run stored in --backend."),
    overwrite: bool = typer.Option(False, "--overwrite", help="With --sample: start the chain in --backend again (a stored chain is kept otherwise)."),
    quiet: bool = typer.Option(False, "--quiet", "-q", help="No progress bars (they show only on a terminal)."),
    workers: Optional[int] = typer.Option(None, "--workers", min=1, help="Fit on a local Dask cluster of this many worker processes (needs -o; results are kept per file and a re-run skips the files done)."),
    scheduler: Optional[str] = typer.Option(None, "--scheduler", help="Fit on an existing Dask cluster: the scheduler's address (tcp://HOST:8786) or its scheduler file (.json); as --workers otherwise."),
):
    """Fit the Cook–Torrance parameters to DATA; prints a table of parameters ± standard errors.

    Several files (or folders): each is fitted on its own; a file that cannot be read or fitted
    is reported as 'error: FILE: reason' and the others go on; a summary follows on stderr.
    Exit status: 0 every fit converged, 1 some fit did not converge, 2 a file failed or the
    options are wrong.

    --workers N / --scheduler ADDRESS: the files are fitted on a Dask cluster, each result written
    as it completes, a re-run skipping the files done, OUTDIR/summary.json (docs/scaling.md).
    One texel store (.zarr, .nc, .h5): every texel fitted, -o MAPS.zarr the parameter maps
    (docs/formats.md).
    """
    opts = SimpleNamespace(**locals())
    code = _run(lambda: _fit_command(opts))
    if code:
        raise typer.Exit(code)


def _fit_command(o) -> int:
    """The ``fit`` command: options and outputs checked first, then every file; the exit status."""
    from .._runtime import progress_enabled

    _check_fit_options(o)
    if len(o.data) == 1 and o.data[0].suffix.lower() in _TEXEL_SUFFIXES:
        return _fit_texel_command(o)
    files = _expand(o.data)
    _setup_jax(o.float32)
    _check_fit_choices(o)
    plan = _fit_plan(files, o)
    base = _load_material(o.material) if o.material else None
    if o.workers is not None or o.scheduler is not None:
        outcomes = _fit_on_cluster(files, o, base, plan, progress_enabled(o.quiet))
    else:
        outcomes = _fit_each(files, o, base, plan, progress_enabled(o.quiet))
    return _fit_exit_status(outcomes)


def _check_fit_options(o) -> None:
    """Refuse bad option values before any work (typer's ``min=`` checks the counts)."""
    if o.geometry not in (None, "v-cavity", "smith", "smith-rational"):
        raise UserError(f"--geometry must be v-cavity, smith or smith-rational, got {o.geometry!r}")
    if o.fresnel not in (None, "effective-n", "conductor"):
        raise UserError(f"--fresnel must be effective-n or conductor, got {o.fresnel!r}")
    from .._model import MAX_LOBES

    if o.lobes != "auto" and not (o.lobes.isdigit() and 1 <= int(o.lobes) <= MAX_LOBES):
        raise UserError(f"--lobes must be 1..{MAX_LOBES} or 'auto', got {o.lobes!r}")
    if (o.resume or o.overwrite) and o.backend is None:
        raise UserError(f"{'--resume' if o.resume else '--overwrite'} needs --backend")
    if o.walkers is not None and o.walkers % 2:
        raise UserError(f"--walkers must be even (emcee moves one half of the walkers against the other), got {o.walkers}")
    if o.burn is not None and o.burn >= o.steps:
        raise UserError(f"--burn must be less than --steps ({o.steps}), got {o.burn}")
    if o.workers is not None or o.scheduler is not None:
        _check_cluster_options(o)


def _check_cluster_options(o) -> None:
    """--workers / --scheduler: one structure for all files, results kept in -o."""
    which = "--workers" if o.workers is not None else "--scheduler"
    if o.workers is not None and o.scheduler is not None:
        raise UserError("--workers makes a local cluster and --scheduler uses an existing one: give one of them")
    if o.output is None:
        raise UserError(f"{which} needs -o (the results are written per file as they complete, and a re-run skips the files done)")
    if o.sample_:
        raise UserError(f"{which} fits only; leave out --sample (or sample the files afterwards)")
    if o.lobes == "auto" and o.material is None:
        raise UserError(f"{which} fits one structure to every file; give --lobes N (not auto) or --material")
    if o.as_json:
        raise UserError(f"{which} writes each result to -o; leave out --json")


def _check_fit_choices(o) -> None:
    """Refuse an unknown --loss or --solver before the first file (the library's lists)."""
    from .._fitting import LOSSES, SOLVERS

    if o.loss not in ("auto", *LOSSES):
        raise UserError(f"--loss must be auto or one of {', '.join(LOSSES)}, got {o.loss!r}")
    if o.solver not in SOLVERS:
        raise UserError(f"--solver must be one of {', '.join(SOLVERS)}, got {o.solver!r}")


def _fit_plan(files: list[Path], o) -> dict[Path, SimpleNamespace]:
    """Every file's targets (json, plot, backend; None: not written) and name, checked before any work.

    One file: the paths given; several: distinct files in the folders given (``result_targets``).
    """
    from .._io import check_backend, check_output, check_output_folder, result_targets

    many = len(files) > 1

    def targets(value, option, suffix, check):
        if value is None:
            return dict.fromkeys(files)
        found = result_targets(files, check_output_folder(value, option=option), suffix) if many else {files[0]: Path(value)}
        return {p: check(target) for p, target in found.items()}

    def chain(target):
        return check_backend(target, files, resume=o.resume, overwrite=o.overwrite)

    json_ = targets(o.output, "-o", ".fit.json", lambda t: check_output(t, files, option="-o"))
    plot = targets(o.plot, "--plot", ".fit.png", lambda t: check_output(t, files, option="--plot"))
    backend = targets(o.backend if o.sample_ else None, "--backend", ".h5", chain)
    names = result_targets(files, Path(), "") if many else {files[0]: Path(files[0].stem)}
    return {p: SimpleNamespace(json=json_[p], plot=plot[p], backend=backend[p], name=names[p].name) for p in files}


def _fit_each(files: list[Path], o, base, plan: dict, show: bool) -> list[tuple[str, str]]:
    """Fit every file; several: a failure is one error line and the rest go on. [(outcome, what)].

    Several files fitted with one structure (not ``--lobes auto``, not ``--sample``) are fitted
    together by ``fit_batch``, a window of files at a time (:func:`_fit_together`), and then
    reported file by file, as they would be one at a time."""
    from .._runtime import bar, echo

    together = len(files) > 1 and not o.sample_ and not (o.lobes == "auto" and base is None)
    outcomes, fitted = [], {}
    for k, path in enumerate(bar(files, desc="files", enabled=show and len(files) > 1)):
        try:
            if not together:
                outcome = _fit_file(path, o, base, plan[path], show)
            else:
                if path not in fitted:
                    fitted = _fit_together(files[k:], o, base)
                got = fitted.pop(path)
                if isinstance(got, Exception):
                    raise got
                outcome = _report_file(path, *got, o, plan[path], show)
            outcomes.append((outcome, str(path)))
        except (UserError, ValueError, OSError, KeyError) as e:
            if len(files) == 1:
                raise
            message = _cli_message(str(e))
            line = message if message.startswith(f"{path}:") else f"{path}: {message}"
            echo(f"error: {line}", err=True)
            outcomes.append(("failed", line))
    return outcomes


def _fit_on_cluster(files: list[Path], o, base, plan: dict, show: bool) -> list[tuple[str, str]]:
    """--workers / --scheduler: files whose stored result was fitted from the same bytes with the
    same options are skipped; the others are fitted by ``fit_many`` on the cluster and each is
    reported and written as its task completes. ``summary.json`` goes beside the results."""
    from .._runtime import dask_client
    from .._fitting import fit_many, input_sha256
    from .._runtime import echo

    options = _fit_options_record(o)
    hashes, outcomes, pending = {}, {}, []
    for path in files:
        try:
            hashes[path] = input_sha256(path)
        except OSError as e:
            outcomes[path] = ("failed", f"{path}: {e.strerror or e}")
            continue
        kept = _kept_result(plan[path].json, hashes[path], options)
        if kept is None:
            pending.append(path)
        else:
            outcomes[path] = (kept, f"{path}{_KEPT}")

    def done(i: int, got) -> None:
        path = pending[i]
        try:
            if isinstance(got, Exception):
                raise got
            got.material.meta.update(input_sha256=hashes[path], fit_options=options)
            meas = _read_data(path, o.param_out) if plan[path].plot is not None else None
            outcomes[path] = (_report_file(path, meas, got, o, plan[path], show), str(path))
        except (UserError, ValueError, OSError, KeyError, RuntimeError) as e:
            message = _cli_message(str(e))
            line = message if message.startswith(f"{path}:") else f"{path}: {message}"
            echo(f"error: {line}", err=True)
            outcomes[path] = ("failed", line)

    if pending:
        st = _structure_from_options(base.structure if base else None, int(o.lobes) if o.lobes != "auto" else 1, o.geometry, o.fresnel, o.diffuse)
        kw = _fit_kwargs(o)
        with dask_client(workers=o.workers, scheduler=o.scheduler) as client:
            fit_many([str(p) for p in pending], st, client, material=base, param_out=o.param_out, return_errors=True, on_result=done,
                     progress=show, **kw)
    ordered = [outcomes[p] for p in files]
    if len(files) > 1:
        _write_summary(Path(o.output) / "summary.json", files, ordered, plan, hashes)
    return ordered


_TEXEL_SUFFIXES = (".zarr", ".nc", ".h5", ".hdf5")


def _fit_texel_command(o) -> int:
    """Texel data (``docs/formats.md``): every texel fitted on a Dask cluster (--workers, --scheduler,
    else one local worker per core), the maps written to the Zarr store -o as chunks complete
    (a re-run resumes), PNGs of the maps in the folder --plot. 0: every texel converged, 1: not."""
    from .._runtime import dask_client, echo, progress_enabled
    from .._fitting import fit_texel_maps, save_map_pngs

    if o.output is None or o.output.suffix.lower() != ".zarr":
        raise UserError("texel data: give -o MAPS.zarr (the parameter maps are written there as a Zarr store)")
    if o.sample_ or o.material is not None or o.lobes == "auto" or o.as_json or o.backend is not None:
        raise UserError("texel data: fits with --lobes N only; leave out --sample, --material, --lobes auto, --json and --backend")
    _setup_jax(o.float32)
    _check_fit_choices(o)
    st = _structure_from_options(None, int(o.lobes), o.geometry, o.fresnel, o.diffuse)
    kw = _fit_kwargs(o)
    with dask_client(workers=o.workers, scheduler=o.scheduler) as client:
        maps = fit_texel_maps(o.data[0], o.output, st, client, loss=kw["loss"], solver=kw["solver"], dtype=kw["dtype"], starts=kw["starts"],
                              max_steps=kw["max_steps"], progress=progress_enabled(o.quiet))
    with maps:
        import numpy as np

        converged = int(maps["converged"].sum())
        total = int(maps["converged"].size)
        echo(f"{o.data[0]}: {total} texels, {converged} converged, {total - converged} did not; median rel_rmse "
             f"{float(np.nanmedian(maps['rel_rmse'].values)):.4g}")
        _wrote(o.output)
        if o.plot is not None:
            for png in save_map_pngs(maps, o.plot):
                _wrote(png)
    return 0 if converged == total else 1


_KEPT = " (kept: fitted earlier from the same input)"


def _fit_options_record(o) -> dict:
    """The options a stored result was fitted with (a re-run keeps it only if they are equal)."""
    from .._fitting import input_sha256

    return dict(lobes=o.lobes, geometry=o.geometry, fresnel=o.fresnel, diffuse=o.diffuse, loss=o.loss, solver=o.solver, float32=o.float32,
                starts=o.starts, max_steps=o.max_steps, param_out=o.param_out, material=input_sha256(o.material) if o.material else None)


def _kept_result(target, sha: str, options: dict) -> str | None:
    """'converged' or 'not converged' when ``target`` holds a fit of the same input and options, else None."""
    if target is None or not Path(target).is_file():
        return None
    try:
        doc = json.loads(Path(target).read_text(encoding="utf-8"))
    except (OSError, ValueError):
        return None
    fit = doc.get("fit") if isinstance(doc, dict) else None
    if not isinstance(fit, dict) or doc.get("input_sha256") != sha or doc.get("fit_options") != options:
        return None
    return "converged" if fit.get("converged") is True else "not converged"


def _write_summary(target: Path, files: list[Path], outcomes: list[tuple[str, str]], plan: dict, hashes: dict) -> None:
    """``summary.json``: per file its outcome, result file, input hash and (failed) the reason."""
    from .._io import atomic_write

    rows = []
    for path, (outcome, what) in zip(files, outcomes):
        rows.append(dict(data=str(path), outcome=outcome, kept=what.endswith(_KEPT),
                         result=None if outcome == "failed" else str(plan[path].json), input_sha256=hashes.get(path),
                         reason=what if outcome == "failed" else None))
    count = {k: sum(r["outcome"] == k for r in rows) for k in ("converged", "not converged", "failed")}
    atomic_write(target, [json.dumps(dict(files=len(rows), **count, results=rows), indent=2) + "\n"])
    _wrote(target)


UNUSABLE = "posterior not usable"
"""The outcome of a converged fit whose ``--sample`` posterior is not usable (exit status 1)."""


def _fit_exit_status(outcomes: list[tuple[str, str]]) -> int:
    """Print the summary (several files); 0: all converged (and, with --sample, every posterior
    usable), 1: some did not, 2: some failed."""
    from .._runtime import echo

    count = {k: sum(v == k for v, _ in outcomes) for k in ("converged", "not converged", UNUSABLE, "failed")}
    if len(outcomes) > 1:
        unusable = f", {count[UNUSABLE]} with a posterior that is not usable" if count[UNUSABLE] else ""
        head = (f"summary: {len(outcomes)} files: {count['converged'] + count[UNUSABLE]} converged{unusable}, {count['not converged']} did not converge, "
                f"{count['failed']} failed")
        echo("\n".join([head, *(f"  {v:<14} {what}" for v, what in outcomes)]), err=True)
    elif count["not converged"]:
        echo("error: the fit did not converge (see the table)", err=True)
    elif count[UNUSABLE]:
        echo("error: the posterior is not usable (see its problem lines)", err=True)
    return 2 if count["failed"] else (1 if count["not converged"] or count[UNUSABLE] else 0)


def _fit_file(path: Path, o, base, t: SimpleNamespace, show: bool) -> str:
    """Read, fit, print and write one file's results; its outcome (:func:`_report_file`)."""
    meas = _read_data(path, o.param_out)
    return _report_file(path, meas, _fit_measurement(meas, o, base, show), o, t, show)


def _fit_together(files: list[Path], o, base) -> dict:
    """The first of ``files`` read — one at least, more while they hold fewer than
    ``SAMPLE_BUDGET`` samples in all, so memory stays bounded — and fitted by ``fit_batch``:
    path → (measurement, FitResult), or the exception that stopped that file (reading it, its
    start, or its fit)."""
    from .._fitting import SAMPLE_BUDGET, fit_batch, start_from_material

    st = _structure_from_options(base.structure if base else None, int(o.lobes) if o.lobes != "auto" else 1, o.geometry, o.fresnel, o.diffuse)
    done: dict = {}
    ready, fixed, held = [], (), 0
    for path in files:
        if held >= SAMPLE_BUDGET:
            break
        try:
            meas = _read_data(path, o.param_out)
            start, fixed = start_from_material(base, st, meas) if base else (None, ())
            ready.append((path, meas, start))
            held += len(meas)
        except (UserError, ValueError, OSError, KeyError) as e:
            done[path] = e
    fits = fit_batch([m for _, m, _ in ready], st, start=[s for _, _, s in ready], fixed=fixed, return_errors=True, **_fit_kwargs(o))
    for (path, meas, _), res in zip(ready, fits):
        done[path] = res if isinstance(res, Exception) else (meas, res)
    return done


def _report_file(path: Path, meas, res, o, t: SimpleNamespace, show: bool) -> str:
    """Print and write one file's results; its outcome: "converged", "not converged", or with
    --sample ``UNUSABLE`` when the fit converged but its posterior is not usable."""
    res.material.meta["data"] = str(path)
    target, note = t.json, None
    if target is not None and not res.converged:
        from .._io import unconverged_target

        target, note = unconverged_target(target)
    usable = True
    if o.sample_:
        usable = _sample_and_report(res, meas, path, o, t, target, show)
    else:
        _report_fit(res, path, o, target)
    _wrote(target, note)
    if t.plot is not None:
        from .._fitting import plot_fit

        plot_fit(res, meas, t.plot)
        _wrote(t.plot)
    return "not converged" if not res.converged else ("converged" if usable else UNUSABLE)


def _fit_measurement(meas, o, base, show: bool):
    """One fit: the structure of the options (or --material), or with --lobes auto the lowest BIC."""
    from .._fitting import fit as run_fit, start_from_material
    from .._runtime import echo

    kw = _fit_kwargs(o)
    if o.lobes == "auto" and base is None:
        cands = [_structure_from_options(None, j, o.geometry, o.fresnel, d) for j in (1, 2, 3) for d in (False, True)]
        res, table = _select_structure(meas, cands, kw, show)
        if not o.as_json:
            echo(_bic_table(table, res))
        return res
    lobes = int(o.lobes) if o.lobes != "auto" else 1
    st = _structure_from_options(base.structure if base else None, lobes, o.geometry, o.fresnel, o.diffuse)
    start, fixed = start_from_material(base, st, meas) if base else (None, ())
    return run_fit(meas, st, start=start, fixed=fixed, **kw)


def _fit_kwargs(o) -> dict:
    """The options of ``fit`` (and ``fit_batch``) that the command line sets."""
    import jax.numpy as jnp

    return dict(loss=o.loss, solver=o.solver, dtype=jnp.float32 if o.float32 else jnp.float64, starts=o.starts, max_steps=o.max_steps)


def _select_structure(meas, cands, kw: dict, show: bool):
    """The library's ``select_structure`` (nested starts, lowest BIC), candidate by candidate
    under a progress bar."""
    from .._fitting import select_structure
    from .._runtime import bar

    return select_structure(meas, cands, progress=lambda it: bar(it, desc="structures", enabled=show), **kw)


def _report_fit(res, path: Path, o, target) -> None:
    """The table (or JSON) on stdout; the fit-result JSON written to ``target``."""
    from .._fitting import fit_result_to_dict, format_fit_table
    from .._io import save_material_json
    from .._runtime import echo

    echo(json.dumps(fit_result_to_dict(res), indent=2) if o.as_json else format_fit_table(res, str(path)))
    if target is not None:
        save_material_json(res.material, target, extra=fit_result_to_dict(res, material_keys=False))


def _sample_and_report(res, meas, path: Path, o, t: SimpleNamespace, target, show: bool) -> bool:
    """--sample: the posterior of the fit, its tables (or JSON) on stdout, written to ``target``;
    whether the posterior is usable."""
    import warnings

    from .._fitting import format_fit_table
    from .._runtime import echo
    from .._sampling import ChainTooShortWarning, fit_sample_body, format_uncertainty_table

    with warnings.catch_warnings():
        warnings.simplefilter("ignore", ChainTooShortWarning)  # listed in the table and the JSON
        doc = fit_sample_body(
            res, meas, walkers=o.walkers, steps=o.steps, burn=o.burn, thin=o.thin, seed=o.seed, backend=t.backend,
            resume=o.resume, overwrite=o.overwrite, output=target, plot_dir=None if t.plot is None else t.plot.parent,
            plot_stem=t.name, progress=show,
        )
    if o.as_json:
        echo(json.dumps(doc, indent=2))
    else:
        echo(format_fit_table(res, str(path)))
        echo(format_uncertainty_table(doc, str(path)))
    return bool(doc["uncertainty"]["usable"])


def _wrote(target, note: str | None = None) -> None:
    """'wrote TARGET' on stderr, on its own line after what went to stdout (and a note before it)."""
    from .._runtime import echo

    if note:
        echo(f"warning: {note}", err=True)
    if target is not None:
        echo(f"wrote {target}", err=True)


def _expand(paths) -> list[Path]:
    """The measurement files named, folders expanded (sorted); each file once."""
    files: dict[Path, None] = {}
    for p in paths:
        if p.is_dir():
            found = sorted(q for q in p.iterdir() if q.suffix.lower() in (".csv", ".binary", ".alta", ".dat"))
            if not found:
                raise UserError(f"{p}: folder has no measurement files (.csv, .binary, .alta, .dat)")
            files.update(dict.fromkeys(found))
        elif not p.exists():
            raise UserError(f"{p}: no such file")
        else:
            files[p] = None
    return list(files)


def _bic_table(table, best) -> str:
    lines = [
        "model selection (lowest BIC wins):",
        f"  {'lobes':>5} {'diffuse':>8} {'params':>6} {'rel_rmse':>10} {'BIC':>14} {'converged':>10}",
    ]
    for st, r in table:
        mark = "  <- kept" if r is best else ""
        s = r.stats
        lines.append(f"  {st.lobes:>5} {str(st.has_diffuse):>8} {s['n_params']:>6} {s['rel_rmse']:>10.4g} {s['bic']:>14.6g} {str(bool(r.converged)):>10}{mark}")
    return "\n".join(lines)


SAMPLE_NOT_USABLE = 1
"""Exit status of ``ctfit sample`` when the chain ran but its posterior is not usable (it left the
fit, runs to a prior bound, or the data do not constrain a parameter): the table and the JSON say why."""


@app.command("sample")
def sample_cmd(
    fit_json: Path = typer.Argument(..., help="Fit-result JSON (a material TOML needs -o)."),
    data: Path = typer.Argument(..., help="The measurement the material was fitted to."),
    output: Optional[Path] = typer.Option(None, "-o", "--output", help="Write the JSON here (default: update FIT_JSON in place)."),
    as_json: bool = typer.Option(False, "--json", help="Print the resulting JSON instead of the table."),
    loss: Optional[str] = typer.Option(None, "--loss", help="absolute, relative, sigma, cosine or log (default: the fit's); another than the fit's fits again first."),
    walkers: Optional[int] = typer.Option(None, "--walkers", min=2, help="Walkers (default max(2·ndim + 2, 32), even)."),
    steps: int = typer.Option(2000, "--steps", min=1, help="Steps per walker in all (also with --resume)."),
    burn: Optional[int] = typer.Option(None, "--burn", min=0, help="Steps discarded (default max(2 τ, steps/10), at most steps/2)."),
    thin: int = typer.Option(1, "--thin", min=1, help="Keep every THIN-th step."),
    seed: int = typer.Option(0, "--seed"),
    backend: Optional[Path] = typer.Option(None, "--backend", help="HDF5 file keeping the chain (emcee HDFBackend)."),
    resume: bool = typer.Option(False, "--resume", help="Continue the run stored in --backend up to --steps."),
    overwrite: bool = typer.Option(False, "--overwrite", help="Start a new chain in an existing --backend file (its chain is lost)."),
    plot: Optional[Path] = typer.Option(None, "--plot", help="Folder for the corner and spectral-band PNGs."),
    idata: Optional[Path] = typer.Option(None, "--idata", help="Also write the chain as ArviZ netCDF (az.from_netcdf) to this file."),
    param_out: Optional[str] = typer.Option(None, "--param-out", help=_PARAM_OUT_HELP),
    quiet: bool = typer.Option(False, "--quiet", "-q", help="No progress bar (shown only on a terminal)."),
):
    """Posterior sampling (emcee) of a fitted material: medians and 68 %/95 % intervals, written into the fit JSON.

    Exit status: 0 a usable posterior; 1 the chain ran but its posterior is not usable (it left
    the fit, runs to a prior bound, or the data do not constrain a parameter; the table and the
    JSON's uncertainty.problems say why); 2 an input error.
    """
    opts = SimpleNamespace(**locals())
    code = _run(lambda: _sample_command(opts))
    if code:
        raise typer.Exit(code)


def _check_sample_options(o) -> Path:
    """Options and outputs checked before any work; returns the JSON target."""
    from .._io import check_backend, check_output, check_output_folder
    from .._fitting import LOSSES

    if (o.resume or o.overwrite) and o.backend is None:
        raise UserError(f"{'--resume' if o.resume else '--overwrite'} needs --backend")
    if o.loss is not None and o.loss not in LOSSES:
        raise UserError(f"--loss must be one of {', '.join(LOSSES)}, got {o.loss!r}")
    target = check_output(o.output or o.fit_json, [o.data], option="-o" if o.output else "")
    if o.backend is not None:
        check_backend(o.backend, [o.fit_json, o.data, target], resume=o.resume, overwrite=o.overwrite)
    if o.idata is not None:
        check_output(o.idata, [o.fit_json, o.data, target], option="--idata")
    if o.plot is not None:
        check_output_folder(o.plot, "--plot")
    return target


def _sample_command(o) -> int:
    """The ``sample`` command's body: the exit status (0, or ``SAMPLE_NOT_USABLE``)."""
    _check_sample_options(o)
    _setup_jax()
    import warnings

    from .._runtime import progress_enabled
    from .._sampling import ChainTooShortWarning, format_uncertainty_table, sample_command_body

    meas = _read_data(o.data, o.param_out)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", ChainTooShortWarning)  # listed in the table and the JSON
        doc = sample_command_body(
            o.fit_json, meas, o.walkers, o.steps, o.burn, o.thin, o.seed, o.backend, o.resume, o.plot, o.output,
            progress=progress_enabled(o.quiet), overwrite=o.overwrite, loss=o.loss, idata=o.idata,
        )  # fmt: skip
    typer.echo(json.dumps(doc, indent=2) if o.as_json else format_uncertainty_table(doc, str(o.data)))
    typer.echo(f"wrote {o.output or o.fit_json}", err=True)
    return 0 if doc["uncertainty"]["usable"] else SAMPLE_NOT_USABLE


@app.command()
def render(
    materials: List[Path] = typer.Argument(..., help="Material TOML or fit-result JSON files, one tile each."),
    output: Path = typer.Option(..., "-o", "--output", help="Output PNG."),
    size: int = typer.Option(256, "--size", min=8, help="Tile side in pixels."),
    shape: str = typer.Option("sphere", "--shape", help="sphere or vase."),
    compare: Optional[Path] = typer.Option(None, "--compare", help="Measurement file: show the one MATERIAL beside a rendering that uses the nearest measured BRDF."),
    labels: bool = typer.Option(True, "--labels/--no-labels", help="Write each material's name under its tile."),
    columns: Optional[int] = typer.Option(None, "--columns", min=1, help="Tiles per row (default: up to 6)."),
    step: float = typer.Option(5.0, "--step", min=0.0, help="Wavelength step of spectral rendering over 380–780 nm."),
    supersample: int = typer.Option(2, "--supersample", min=1, max=8, help="Samples per pixel along each axis (anti-aliasing)."),
    ambient: float = typer.Option(0.01, "--ambient", min=0.0, help="Ambient irradiance as a fraction of the two lights' (the paper's 1 %)."),
    exposure: str = typer.Option("reference", "--exposure", help="reference: the paper's scaling with a white reference object; tile: the tile alone."),
):
    """Render materials on spheres or vases under the paper's two lights (Figures 6–7) to a PNG."""

    def body():
        from .._io import check_output

        check_output(output, [*materials, compare])
        _setup_jax(float32=True)  # float32 is plenty for images
        from .render_command import render_command_body

        info = render_command_body(
            materials, output, size, shape, compare, labels,
            columns=columns, wavelength_step=step, supersample=supersample, ambient=ambient, exposure=exposure,
        )
        h, w = info["image_shape"][:2]
        typer.echo(f"wrote {info['output']} ({w} × {h} pixels, {len(materials)} material(s))", err=True)

    _run(body)


@app.command()
def color(
    material: Path = typer.Argument(..., help="Material TOML or fit-result JSON."),
    angle: float = typer.Option(0.0, "--angle", help="Angle of incidence, degrees."),
    illuminant: str = typer.Option("D65", "--illuminant", help="CIE illuminant (colour-science's name): D65, A, D50, …"),
    colourspace: str = typer.Option("sRGB", "--colorspace", "--colourspace", help="RGB colourspace (colour-science's name); --colourspace is the same option."),
    as_json: bool = typer.Option(False, "--json", help="Print JSON instead of the table."),
):
    """The material's reflectance colour at normal incidence (or --angle): XYZ, xy, RGB, Lab, …

    The CLI spells colour the American way (``color``, ``--colorspace``); ``ctfit colour`` and
    ``--colourspace`` are the same command and option."""

    def body():
        _setup_jax()
        from .._colour import colour_report

        mat = _load_material(material)
        rep = colour_report(mat, angle_deg=angle, illuminant=illuminant, colourspace=colourspace)
        if as_json:
            typer.echo(json.dumps(rep, indent=2, default=float))
        else:
            for k, v in rep.items():
                typer.echo(f"{k:>24}: {v}")

    _run(body)


app.command("colour", hidden=True, help="The same as ctfit color.")(color)


def _interrupted_message() -> str:
    """``interrupted``; after a chain was started in an HDF5 backend, the command that resumes it."""
    import shlex

    from .._io import resumable

    args = sys.argv[1:]
    has_backend = any(a == "--backend" or a.startswith("--backend=") for a in args)
    if has_backend and (resumable() is not None or "--resume" in args):
        again = [a for a in args if a != "--overwrite"] + ([] if "--resume" in args else ["--resume"])
        return "interrupted; resume with: ctfit " + shlex.join(again)
    return "interrupted"


def main():  # console-script entry point
    """Run the command; Ctrl-C at any moment exits with status 130 and one line (``_io/interrupt.py``)."""
    from .._runtime import matplotlib_config_fallback
    from .._io import install
    from .._runtime import return_large_blocks

    install(_interrupted_message)
    return_large_blocks()  # peak memory: what a command holds at once (``_runtime/memory.py``)
    matplotlib_config_fallback()  # no HOME: the compilation cache's one warning says it all
    app()

if __name__ == "__main__":
    main()
