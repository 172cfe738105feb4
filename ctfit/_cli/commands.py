"""The ``ctfit`` command: eval, simulate, fit, sample, color, render (the typer app; the bodies of
``fit`` and ``sample`` live in ``fit_command.py``, ``fit_cluster.py`` and ``sample_command.py``).

Heavy imports (JAX, colour-science) happen inside the commands, so ``ctfit --version`` is fast.
Errors in the input (bad files, bad options) print one ``error:`` line naming the file, line
and column where known, and exit with status 2; a fit that does not converge exits with 1.
Warnings print as one line ``warning: MESSAGE``; ``fit`` over several files goes on after a
file's error and ends with a summary (docs/fitting.md). Outputs are checked before any work
(``_io/output_paths.py``); Ctrl-C exits with status 130 and one line, ``interrupted`` (``_cli/interrupt.py``).
"""

from __future__ import annotations

import contextlib
import json
import sys
from pathlib import Path
from types import SimpleNamespace
from typing import Optional

import typer

from .._sampling import MAX_SEED, MAX_STEPS, MAX_WALKERS  # (no JAX: ctfit._sampling.run_limits)
from .inputs import (
    PARAM_OUT_HELP,
    WAVELENGTHS_HELP,
    data_bands_check,
    load_coloured_material,
    load_material_file,
    material_inputs,
    output_file,
    parse_wavelengths,
    read_data,
    refuse_dash,
    setup_jax,
)
from .messages import UserError, cli_message, echo, run_body

app = typer.Typer(add_completion=False, no_args_is_help=True, rich_markup_mode=None, help="Fit the Cook–Torrance reflectance model to BRDF samples.")


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


@app.command("eval")
def eval_cmd(
    material: Path = typer.Argument(..., help="Material TOML or fit-result JSON."),
    data: Path = typer.Argument(..., help="Measurement CSV (a 'brdf' column is optional and replaced)."),
    output_text: str = typer.Option(..., "-o", "--output", help="Output CSV."),
    float32: bool = typer.Option(False, "--float32", help="Evaluate in float32 (default float64)."),
    param_out: Optional[str] = typer.Option(None, "--param-out", help=PARAM_OUT_HELP),
):
    """The material's BRDF at every row of DATA, written as a measurement CSV."""

    def body():
        from .._io import check_output

        output = output_file(output_text)
        check_output(output, [*material_inputs(material), data])
        setup_jax(float32)
        from .._io import write_csv
        from .._model import evaluate

        mat = load_material_file(material)
        meas = read_data(data, param_out)
        data_bands_check(mat, material, meas, data)
        bands = len(mat.band_labels)
        if meas.band_unknown and not mat.band_unknown and bands > 1:
            raise UserError(f"{data}: its one band has no known wavelength, and the material's values differ from band to band "
                            f"({bands} bands): there is no telling which to evaluate; give the data a wavelength (a CSV)")
        import numpy as np

        values = np.asarray(evaluate(mat, meas))
        bad = np.flatnonzero(~np.isfinite(values))
        if bad.size:  # the model's, not the data's: Measurement(brdf=values) named the data file and a 'brdf' it did not have
            slope = f"m = {float(np.min(mat.params.m)):g}; ctfit fits m ≥ 1e-5" if mat.params.m is not None else "its parameters"
            place = meas.file_place(int(bad[0]), "theta_i")  # a CSV's line
            first = f"line {place[0]}, " if place is not None else ""
            raise UserError(f"{material}: the model is not finite at {bad.size} of {len(values)} rows of {data} "
                            f"(the first: {first}θ_i {meas.theta_i[bad[0]]:g}°, θ_o {meas.theta_o[bad[0]]:g}°): its values overflow "
                            f"{'float32' if float32 else 'float64'} there ({slope})"
                            + ("; evaluate it in float64" if float32 else ""))
        # The values are the model's: the data's own lines (its source, noise, instrument) would describe them wrongly.
        meta = {"source": "ctfit eval", "material": str(material), "directions": str(data)}  # (write_csv adds '# band: unknown' where it is)
        write_csv(meas.replace(brdf=values, sigma=None, meta=meta), output)
        echo(f"wrote {len(values)} samples to {output}", err=True)

    run_body(body)


@app.command()
def simulate(
    material: Path = typer.Argument(..., help="Material TOML or fit-result JSON."),
    output_text: str = typer.Option(..., "-o", "--output", help="Output CSV."),
    samples: int = typer.Option(2000, "--samples", min=1, help="Direction pairs (each measured in every band)."),
    seed: int = typer.Option(0, "--seed", min=0),
    noise: float = typer.Option(0.0, "--noise", min=0.0, help="Relative Gaussian noise (0.02 = 2 %); adds a sigma column."),
    wavelengths: Optional[str] = typer.Option(None, "--wavelengths", help=WAVELENGTHS_HELP),
    max_theta: float = typer.Option(85.0, "--max-theta", help="Largest polar angle of light and viewer, degrees: above 0, below 90."),
):
    """Synthetic goniometric measurements of MATERIAL (denser near the mirror direction)."""

    def body():
        from .._io import check_output

        output = output_file(output_text)
        check_output(output, material_inputs(material))
        setup_jax()
        from .._io import write_csv
        from .._model import simulate as sim

        mat = load_material_file(material)
        if mat.band_unknown and wavelengths is not None:
            raise UserError(f"{material}: the material has one band of unknown wavelength (band_unknown: a fit of single-band data such as "
                            "an ALTA file); it has no values at --wavelengths: leave the option out (the CSV then says '# band: unknown')")
        meas = sim(mat, samples, wavelength_nm=parse_wavelengths(wavelengths), noise=noise, seed=seed, max_theta=max_theta)
        meta = dict(meas.meta, material=str(material))
        write_csv(meas.replace(meta=meta), output)
        pairs, bands = f"{samples} direction pair{'s' * (samples != 1)}", f"{meas.n_bands} band{'s' * (meas.n_bands != 1)}"
        echo(f"wrote {len(meas)} sample{'s' * (len(meas) != 1)} ({pairs} × {bands}) to {output}", err=True)

    run_body(body)


@app.command()
def fit(
    data: list[Path] = typer.Argument(..., metavar="DATA", help="Measurement files (CSV, ALTA, MERL .binary, RGL .bsdf) or folders of them."),
    output: Optional[str] = typer.Option(None, "-o", "--output", help="Write the fit-result JSON here (one file: this path; several, a folder of them, a name "
                                                                      "ending in / or an existing folder: a folder, with summary.json)."),
    as_json: bool = typer.Option(False, "--json", help="Print the fit-result JSON to stdout instead of the table (several inputs: JSON Lines)."),
    material: Optional[Path] = typer.Option(None, "--material", help="Material file: structure, starting values and (key 'fixed') fixed parameters."),
    family: str = typer.Option("auto", "--family", help="metal (F0(λ), or n, k), plastic (one real index n, its own R_d(λ)) or auto (chosen by the data: "
                                                        "docs/fitting.md)."),
    lobes: str = typer.Option("auto", "--lobes", help="Number of lobes, or auto (1–3, chosen by the data: by BIC, or above 4,096 samples by the error on "
                                                      "held-out direction pairs)."),
    geometry: Optional[str] = typer.Option(None, "--geometry", help="v-cavity (default), smith or smith-rational (Smith with the rational G1 of Mitsuba 3)."),
    fresnel: Optional[str] = typer.Option(None, "--fresnel", help="effective-n (k = 0, n from F0) or conductor (n, k); not given: effective-n, "
                                                              "and a metal the data chooses tries both."),
    diffuse: str = typer.Option("auto", "--diffuse", help="The diffuse part: none, F0/pi (metal), spectrum, constant, transmitted (plastic) or auto (chosen "
                                                          "by the data)."),
    no_diffuse: bool = typer.Option(False, "--no-diffuse", help="No diffuse part (the same as --diffuse none)."),
    loss: str = typer.Option("auto", "--loss", help="auto (sigma with a sigma column, else robust-relative), absolute, relative, robust-relative, sigma, "
                                                    "cosine, log or log-ratio (docs/fitting.md)."),
    solver: str = typer.Option("lm", "--solver", help="lm, gauss-newton, dogleg or bfgs."),
    float32: bool = typer.Option(False, "--float32", help="Fit in float32 (default float64)."),
    starts: int = typer.Option(3, "--starts", min=1, help="Seeds from the grid over m, solved at once."),
    max_steps: int = typer.Option(256, "--max-steps", min=1, help="Solver steps per start (more for a fit that stops short of a minimum)."),
    param_out: Optional[str] = typer.Option(None, "--param-out", help=PARAM_OUT_HELP + " A file's own line wins."),
    plot: Optional[str] = typer.Option(None, "--plot", help="Write a PNG (or PDF, SVG, …: the suffix) of data vs fit, polar plots per incidence angle and the "
                                                            "residual map over (θ_h, θ_d) (one file: this path; several or a folder: a folder, as -o)."),
    sample_: bool = typer.Option(False, "--sample", help="Also sample the posterior (emcee) and add an 'uncertainty' section."),
    walkers: Optional[int] = typer.Option(None, "--walkers", min=2, max=MAX_WALKERS, help="With --sample: walkers, even (default max(2·ndim + 2, 32))."),
    steps: int = typer.Option(2000, "--steps", min=1, max=MAX_STEPS, help="With --sample: steps per walker."),
    burn: Optional[int] = typer.Option(None, "--burn", min=0, help="With --sample: steps discarded (fewer than --steps)."),
    thin: int = typer.Option(1, "--thin", min=1, help="With --sample: keep every THIN-th step."),
    seed: int = typer.Option(0, "--seed", min=0, max=MAX_SEED, help="With --sample: random seed."),
    backend: Optional[str] = typer.Option(None, "--backend", help="With --sample: HDF5 chain file (several data files: a folder, as -o)."),
    resume: bool = typer.Option(False, "--resume", help="With --sample: continue the run stored in --backend."),
    overwrite: bool = typer.Option(False, "--overwrite", help="With --sample: start the chain in --backend again (a stored chain is kept otherwise)."),
    quiet: bool = typer.Option(False, "--quiet", "-q", help="No progress bars (they show only on a terminal)."),
    workers: Optional[int] = typer.Option(None, "--workers", min=1, help="Fit on a local Dask cluster of this many worker processes (needs -o; results are "
                                                                         "kept per file and a re-run skips the files done)."),
    scheduler: Optional[str] = typer.Option(None, "--scheduler", help="Fit on an existing Dask cluster: the scheduler's address (tcp://HOST:8786) or its "
                                                                      "scheduler file (.json); as --workers otherwise."),
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
    from .fit_command import fit_command

    code = run_body(lambda: fit_command(opts))
    if code:
        raise typer.Exit(code)


SAMPLE_NOT_USABLE = 1
"""Exit status of ``ctfit sample`` when the chain ran but its posterior is not usable (it left the
fit, runs to a prior bound, or the data do not constrain a parameter): the table and the JSON say why."""


@app.command("sample")
def sample_cmd(
    fit_json: Path = typer.Argument(..., help="Fit-result JSON or material TOML (read only)."),
    data: Path = typer.Argument(..., help="The measurement the material was fitted to."),
    output: Optional[str] = typer.Option(None, "-o", "--output", help="Write the JSON here (default: STEM.posterior.json beside FIT_JSON, which is never "
                                                                      "written unless -o names it)."),
    as_json: bool = typer.Option(False, "--json", help="Print the resulting JSON instead of the table."),
    loss: Optional[str] = typer.Option(None, "--loss", help="absolute, relative, sigma, cosine, log or log-ratio (default: the fit's; a robust-relative fit "
                                                            "is sampled with the relative likelihood); another than the fit's fits again first."),
    walkers: Optional[int] = typer.Option(None, "--walkers", min=2, max=MAX_WALKERS, help="Walkers (default max(2·ndim + 2, 32), even)."),
    steps: int = typer.Option(2000, "--steps", min=1, max=MAX_STEPS, help="Steps per walker in all (also with --resume)."),
    burn: Optional[int] = typer.Option(None, "--burn", min=0, help="Steps discarded (default max(2 τ, steps/10), at most steps/2 and steps − THIN)."),
    thin: int = typer.Option(1, "--thin", min=1, help="Keep every THIN-th step."),
    seed: int = typer.Option(0, "--seed", min=0, max=MAX_SEED),
    backend: Optional[str] = typer.Option(None, "--backend", help="HDF5 file keeping the chain (emcee HDFBackend)."),
    resume: bool = typer.Option(False, "--resume", help="Continue the run stored in --backend up to --steps."),
    overwrite: bool = typer.Option(False, "--overwrite", help="Start a new chain in an existing --backend file "
                                   "(it replaces the stored one when it ends, or on Ctrl-C after a step)."),
    plot: Optional[Path] = typer.Option(None, "--plot", help="Folder for the corner and spectral-band PNGs."),
    idata: Optional[str] = typer.Option(None, "--idata", help="Also write the chain as ArviZ netCDF (az.from_netcdf) to this file."),
    param_out: Optional[str] = typer.Option(None, "--param-out", help=PARAM_OUT_HELP),
    quiet: bool = typer.Option(False, "--quiet", "-q", help="No progress (a bar on a terminal, else a line every few seconds on stderr)."),
):
    """Posterior sampling (emcee) of a fitted material: medians and 68 %/95 % intervals, written with the fit into STEM.posterior.json (or -o).

    Exit status: 0 a usable posterior; 1 the chain ran but its posterior is not usable (the
    walkers have not mixed, it left the fit, runs to a prior bound, or the data do not
    constrain a parameter; the table and the JSON's uncertainty.problems say why, and a chain
    that has not mixed, how many --steps would do); 2 an input error.
    """
    opts = SimpleNamespace(**locals())
    code = run_body(lambda: _sample_command(opts))
    if code:
        raise typer.Exit(code)


def _check_sample_options(o, hold: contextlib.ExitStack) -> Path:
    """Options and outputs checked before any work; returns the JSON target. The --backend
    file's lock is taken into ``hold`` (:func:`~ctfit._io.output_paths.check_backend`)."""
    from .._fitting import LOSSES
    from .._io import check_backend, check_distinct, check_output, check_output_folder
    from .._runtime import need

    need("posterior", "ctfit sample")
    if o.plot is not None:
        need("plots", "--plot")
        refuse_dash(str(o.plot), "--plot")
    if (o.resume or o.overwrite) and o.backend is None:
        raise UserError(f"{'--resume' if o.resume else '--overwrite'} needs --backend")
    if o.loss is not None and o.loss not in LOSSES:
        raise UserError(f"--loss must be one of {', '.join(LOSSES)}, got {o.loss!r}")
    o.output, o.backend, o.idata = output_file(o.output), output_file(o.backend, "--backend"), output_file(o.idata, "--idata")
    from .sample_command import check_default_output, check_posterior_plots, default_output, result_stem

    target = check_output(o.output or default_output(o.fit_json), [o.fit_json, o.data] if o.output is None else [o.data], option="-o" if o.output else "")
    if o.output is None:
        check_default_output(target)
    if o.backend is not None:
        check_backend(o.backend, [o.fit_json, o.data], resume=o.resume, overwrite=o.overwrite, hold=hold)
    if o.idata is not None:
        check_output(o.idata, [o.fit_json, o.data], option="--idata")
    check_distinct([("-o" if o.output else "the result", target), ("--backend", o.backend), ("--idata", o.idata)])
    if o.plot is not None:
        check_output_folder(o.plot, "--plot")
        check_posterior_plots(o.plot, result_stem(target))
    return target


def _sample_command(o) -> int:
    """The ``sample`` command's body: the exit status (0, or ``SAMPLE_NOT_USABLE``). A --backend
    file that another run is writing is refused at once; this run's lock on it is held until
    the command ends."""
    with contextlib.ExitStack() as hold:
        target = _check_sample_options(o, hold)
        return _sampled(o, target)


def _sampled(o, target: Path) -> int:
    """Sample, print the table (or JSON), write ``target``; the exit status."""
    setup_jax()
    import warnings

    from .._io import load_material
    from .._runtime import progress_mode
    from .._sampling import ChainTooShortWarning, format_uncertainty_table
    from .sample_command import run_longer, sample_command_body

    meas = read_data(o.data, o.param_out)
    data_bands_check(load_material(o.fit_json), o.fit_json, meas, o.data)  # the data file named, before any sampling
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", ChainTooShortWarning)  # listed in the table and the JSON
        doc = sample_command_body(
            o.fit_json, meas, o.walkers, o.steps, o.burn, o.thin, o.seed, o.backend, o.resume, o.plot, target,
            progress=progress_mode(o.quiet), overwrite=o.overwrite, loss=o.loss, idata=o.idata,
        )  # fmt: skip
    echo(json.dumps(doc, indent=2) if o.as_json else cli_message(format_uncertainty_table(doc, str(o.data))))
    hint = run_longer(doc, backend=o.backend)
    if hint:
        echo(hint, err=True)
    echo(f"wrote {target}", err=True)
    return 0 if doc["uncertainty"]["usable"] else SAMPLE_NOT_USABLE


@app.command()
def render(
    materials: list[Path] = typer.Argument(..., help="Material TOML or fit-result JSON files, one tile each."),
    output_text: str = typer.Option(..., "-o", "--output", help="Output PNG."),
    size: int = typer.Option(256, "--size", min=8, help="Tile side in pixels."),
    shape: str = typer.Option("sphere", "--shape", help="sphere or vase."),
    compare: Optional[Path] = typer.Option(None, "--compare", help="Measurement file: show the one MATERIAL beside a rendering that uses the nearest measured "
                                                                   "BRDF."),
    labels: bool = typer.Option(True, "--labels/--no-labels", help="Write each material's name under its tile."),
    columns: Optional[int] = typer.Option(None, "--columns", min=1, help="Tiles per row (default: up to 6)."),
    step: float = typer.Option(5.0, "--step", help="Wavelength step of spectral rendering over 380–780 nm: 1 to 20 nm."),
    supersample: int = typer.Option(2, "--supersample", min=1, max=8, help="Samples per pixel along each axis (anti-aliasing)."),
    ambient: float = typer.Option(0.01, "--ambient", min=0.0, help="Ambient irradiance as a fraction of the two lights' (the paper's 1 %), at most 1e6."),
    exposure: str = typer.Option("reference", "--exposure", help="reference: the paper's scaling with a white reference object; tile: the tile alone."),
    delta_e: bool = typer.Option(False, "--delta-e", help="With --compare: a figure measured (interpolated) | fitted | ΔE2000, its median and 95th percentile "
                                                          "in the title."),
):
    """Render materials on spheres or vases under the paper's two lights (Figures 6–7) to a PNG."""

    def body():
        from .._io import check_output
        from .._runtime import need

        need("plots", "ctfit render")
        output = output_file(output_text)
        check_output(output, [*material_inputs(*materials), compare])
        setup_jax(float32=True)  # float32 is plenty for images
        from .render_command import render_command_body

        info = render_command_body(
            materials, output, size, shape, compare, labels,
            columns=columns, wavelength_step=step, supersample=supersample, ambient=ambient, exposure=exposure, delta_e=delta_e,
        )
        h, w = info["image_shape"][:2]
        echo(f"wrote {info['output']} ({w} × {h} pixels, {len(materials)} material(s))", err=True)
        if info["delta_e"] is not None:
            d = info["delta_e"]
            from .._render import coverage_text

            echo(f"ΔE2000 over the sphere: median {d['median']:.2f}, 95th percentile {d['p95']:.2f} "
                 f"({coverage_text(d['coverage'])} of the lit sphere inside the measured domain)", err=True)

    run_body(body)


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
        setup_jax()
        from .._colour import colour_report

        mat = load_coloured_material(material)
        rep = colour_report(mat, angle_deg=angle, illuminant=illuminant, colourspace=colourspace)
        echo(json.dumps(rep, indent=2, default=float) if as_json else _colour_table(rep))

    run_body(body)


app.command("colour", hidden=True, help="The same as ctfit color.")(color)


def _colour_table(rep: dict) -> str:
    """``ctfit color``'s table: numbers to six significant digits (the JSON keeps every digit), and
    the ``sRGB`` row only where ``rgb`` is of another colourspace."""
    import numpy as np

    def shown(v):
        if isinstance(v, (list, tuple, np.ndarray)):
            return "[" + ", ".join(shown(x) for x in v) + "]"
        return f"{v:.6g}" if isinstance(v, (float, np.floating)) else str(v)

    same = rep.get("colourspace") == "sRGB"
    return "\n".join(f"{k:>24}: {shown(v)}" for k, v in rep.items() if not (same and k == "sRGB"))


@app.command("export")
def export_cmd(
    material: Path = typer.Argument(..., help="Material TOML or fit-result JSON."),
    to: str = typer.Option(..., "--to", help="mitsuba (Mitsuba 3 XML), mitsuba-dict (the same as JSON: mi.load_dict(doc['bsdf'])), merl (.binary table) or "
                                             "gltf (glTF 2.0 material)."),
    output_text: str = typer.Option(..., "-o", "--output", help="Output file."),
    mitsuba_plastic: str = typer.Option("exact", "--mitsuba-plastic", help="exact: a plastic as a blendbsdf of roughconductor and plastic (exact with "
                                                                           "smith-rational G); roughplastic: Mitsuba's roughplastic, its error measured with "
                                                                           "Mitsuba."),
    mitsuba_colour: str = typer.Option("spectrum", "--mitsuba-colour", help="A spectral material's spectra for Mitsuba — spectrum: as spectra, exact in "
                                                                          "its *_spectral variants; rgb: as linear-sRGB colours, for its RGB variants "
                                                                          "(F0's colour as an effective index per channel), the error against the fit's "
                                                                          "colour."),
):
    """Write the material for a renderer, and print how far the export is from the fit in one line.

    The line (also kept in the output: an XML comment, a JSON field) gives the median and maximum
    relative difference of the BRDF over a hemisphere grid; docs/export.md has the mapping. It goes
    to standard error where the output is a device or a pipe (``-o /dev/stdout``)."""

    def body():
        from .._io import check_output, writes_in_place

        output = output_file(output_text)
        formats = ("mitsuba", "mitsuba-dict", "merl", "gltf")
        if to not in formats:
            raise UserError(f"--to {to}: not a format ctfit exports; one of {', '.join(formats)}")
        if mitsuba_plastic not in ("exact", "roughplastic"):
            raise UserError(f"--mitsuba-plastic {mitsuba_plastic}: one of exact, roughplastic")
        if mitsuba_colour not in ("spectrum", "rgb"):
            raise UserError(f"--mitsuba-colour {mitsuba_colour}: one of spectrum, rgb")
        check_output(output, material_inputs(material))
        setup_jax()
        from .._export import export_material

        line = export_material(load_coloured_material(material), to=to, path=output, mitsuba_plastic=mitsuba_plastic,
                               mitsuba_colour=mitsuba_colour).line()
        echo(line, err=writes_in_place(output))  # -o /dev/stdout (or a pipe): the file alone on the stream

    run_body(body)


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
    """Run the command; Ctrl-C at any moment exits with status 130 and one line (``_cli/interrupt.py``)."""
    from .._runtime import matplotlib_config_fallback, return_large_blocks
    from .interrupt import install

    install(_interrupted_message)
    return_large_blocks()  # peak memory: what a command holds at once (``_runtime/memory.py``)
    matplotlib_config_fallback()  # no HOME: the compilation cache's one warning says it all
    app()

if __name__ == "__main__":
    main()
