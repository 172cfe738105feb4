"""The ``ctfit`` command: eval, simulate, fit, sample, color, render.

Heavy imports (JAX, colour-science) happen inside the commands, so ``ctfit --version`` is fast.
Errors in the input (bad files, bad options) print one ``error:`` line naming the file, line
and column where known, and exit with status 2; a fit that does not converge exits with 1.
"""

from __future__ import annotations

import json
import sys
from pathlib import Path
from typing import List, Optional

import typer

app = typer.Typer(add_completion=False, no_args_is_help=True, help="Fit the Cook–Torrance reflectance model to BRDF samples.")


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
    from ._cache import enable_compilation_cache

    enable_compilation_cache()


def _load_material(path: Path):
    from ._material_io import load_material

    return load_material(path)


def _read_data(path: Path, param_out: str | None = None):
    from ._readers import read_measurement

    is_alta = path.suffix.lower() in (".alta", ".dat")
    return read_measurement(path, param_out=param_out) if (param_out and is_alta) else read_measurement(path)


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


def _run(fn):
    """Run a command body, turning input errors into one line and exit status 2."""
    try:
        return fn()
    except UserError as e:
        typer.echo(f"error: {e}", err=True)
        raise typer.Exit(2)
    except (ValueError, OSError, KeyError) as e:
        typer.echo(f"error: {e}", err=True)
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
        _setup_jax(float32)
        from ._csvio import write_csv
        from ._simulate import evaluate

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
    samples: int = typer.Option(2000, "--samples", help="Direction pairs (each measured in every band)."),
    seed: int = typer.Option(0, "--seed"),
    noise: float = typer.Option(0.0, "--noise", help="Relative Gaussian noise (0.02 = 2 %); adds a sigma column."),
    wavelengths: Optional[str] = typer.Option(None, "--wavelengths", help="START:STOP:STEP or a list, nm (default: the material's within 400–700)."),
    max_theta: float = typer.Option(85.0, "--max-theta", help="Largest polar angle of light and viewer, degrees."),
):
    """Synthetic goniometric measurements of MATERIAL (denser near the mirror direction)."""

    def body():
        _setup_jax()
        from ._csvio import write_csv
        from ._simulate import simulate as sim

        mat = _load_material(material)
        meas = sim(mat, samples, wavelength_nm=_parse_wavelengths(wavelengths), noise=noise, seed=seed, max_theta=max_theta)
        meta = dict(meas.meta, material=str(material))
        write_csv(meas.replace(meta=meta), output)
        typer.echo(f"wrote {len(meas)} samples ({samples} direction pairs × {meas.n_bands} bands) to {output}", err=True)

    _run(body)


def _structure_from_options(base, lobes: int, geometry, fresnel, diffuse):
    from ._material import Structure

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
    data: List[Path] = typer.Argument(..., help="Measurement files (CSV, ALTA, MERL .binary) or folders of them."),
    output: Optional[Path] = typer.Option(None, "-o", "--output", help="Write the fit-result JSON here (one file: this path; several: a folder)."),
    as_json: bool = typer.Option(False, "--json", help="Print the fit-result JSON to stdout instead of the table."),
    material: Optional[Path] = typer.Option(None, "--material", help="Material file: structure, starting values and (key 'fixed') fixed parameters."),
    lobes: str = typer.Option("1", "--lobes", help="Number of lobes, or 'auto' (1–3, with/without diffuse, by BIC)."),
    geometry: Optional[str] = typer.Option(None, "--geometry", help="v-cavity (default) or smith."),
    fresnel: Optional[str] = typer.Option(None, "--fresnel", help="effective-n (default: k = 0, n from F0) or conductor (n, k)."),
    diffuse: bool = typer.Option(True, "--diffuse/--no-diffuse", help="Include a diffuse part R_d = F0/π."),
    loss: str = typer.Option("auto", "--loss", help="auto, absolute, relative, sigma, cosine or log."),
    solver: str = typer.Option("lm", "--solver", help="lm, gauss-newton, dogleg or bfgs."),
    float32: bool = typer.Option(False, "--float32", help="Fit in float32 (default float64)."),
    starts: int = typer.Option(3, "--starts", help="Seeds from the grid over m, solved at once."),
    param_out: Optional[str] = typer.Option(None, "--param-out", help=_PARAM_OUT_HELP),
    plot: Optional[Path] = typer.Option(None, "--plot", help="Write a PNG of data vs fit (one file: this path; several: a folder)."),
    sample_: bool = typer.Option(False, "--sample", help="Also sample the posterior (emcee) and add an 'uncertainty' section."),
    walkers: Optional[int] = typer.Option(None, "--walkers", help="With --sample: walkers (default max(2·ndim + 2, 32))."),
    steps: int = typer.Option(2000, "--steps", help="With --sample: steps per walker."),
    burn: Optional[int] = typer.Option(None, "--burn", help="With --sample: steps discarded."),
    thin: int = typer.Option(1, "--thin", help="With --sample: keep every THIN-th step."),
    seed: int = typer.Option(0, "--seed", help="With --sample: random seed."),
    backend: Optional[Path] = typer.Option(None, "--backend", help="With --sample: HDF5 chain file (several data files: a folder)."),
    resume: bool = typer.Option(False, "--resume", help="With --sample: continue the run stored in --backend."),
):
    """Fit the Cook–Torrance parameters to DATA; prints a table of parameters ± standard errors."""
    status = {"code": 0}

    def body():
        if geometry not in (None, "v-cavity", "smith"):
            raise UserError(f"--geometry must be v-cavity or smith, got {geometry!r}")
        if fresnel not in (None, "effective-n", "conductor"):
            raise UserError(f"--fresnel must be effective-n or conductor, got {fresnel!r}")
        if lobes != "auto" and not (lobes.isdigit() and 1 <= int(lobes) <= 8):
            raise UserError(f"--lobes must be 1..8 or 'auto', got {lobes!r}")
        if resume and backend is None:
            raise UserError("--resume needs --backend")
        _setup_jax(float32)
        import jax.numpy as jnp

        from ._fit import fit as run_fit, select_structure
        from ._fit_io import fit_result_to_dict, format_fit_table, start_from_material
        from ._material_io import save_material_json

        files = _expand(data)
        base = _load_material(material) if material else None
        dtype = jnp.float32 if float32 else jnp.float64
        results = []
        for path in files:
            meas = _read_data(path, param_out)
            if lobes == "auto" and base is None:
                cands = [
                    _structure_from_options(None, j, geometry, fresnel, d) for j in (1, 2, 3) for d in (False, True)
                ]
                res, table = select_structure(meas, cands, loss=loss, solver=solver, dtype=dtype, starts=starts)
                if not as_json:
                    typer.echo(_bic_table(table, res))
            else:
                st = _structure_from_options(base.structure if base else None, int(lobes) if lobes != "auto" else 1, geometry, fresnel, diffuse)
                start, fixed = start_from_material(base, st, meas) if base else (None, ())
                res = run_fit(meas, st, start=start, fixed=fixed, loss=loss, solver=solver, dtype=dtype, starts=starts)
            res.material.meta["data"] = str(path)
            results.append((path, res))
            many = len(files) > 1
            target = None if output is None else (output / (Path(path).stem + ".fit.json") if many else output)
            for folder in ([output] if many and output else []) + ([backend] if many and backend and sample_ else []):
                folder.mkdir(parents=True, exist_ok=True)
            if sample_:
                import warnings

                from ._sample import ChainTooShortWarning
                from ._sample_io import fit_sample_body, format_uncertainty_table

                be = None if backend is None else (backend / (Path(path).stem + ".h5") if many else backend)
                with warnings.catch_warnings():
                    warnings.simplefilter("ignore", ChainTooShortWarning)  # listed in the table and the JSON
                    doc = fit_sample_body(
                        res, meas, walkers=walkers, steps=steps, burn=burn, thin=thin, seed=seed, backend=be,
                        resume=resume, output=target, plot_dir=None if plot is None else (plot if many else plot.parent),
                        plot_stem=Path(path).stem, progress=sys.stderr.isatty(),
                    )
                if as_json:
                    typer.echo(json.dumps(doc, indent=2))
                else:
                    typer.echo(format_fit_table(res, str(path)))
                    typer.echo(format_uncertainty_table(doc, str(path)))
            else:
                if as_json:
                    typer.echo(json.dumps(fit_result_to_dict(res), indent=2))
                else:
                    typer.echo(format_fit_table(res, str(path)))
                if target is not None:
                    save_material_json(res.material, target, extra=fit_result_to_dict(res, material_keys=False))
            if target is not None:
                typer.echo(f"wrote {target}", err=True)
            if plot is not None:
                from ._fit_plot import plot_fit

                target = plot if len(files) == 1 else plot / (Path(path).stem + ".fit.png")
                if len(files) > 1:
                    plot.mkdir(parents=True, exist_ok=True)
                plot_fit(res, meas, target)
                typer.echo(f"wrote {target}", err=True)
            if not res.converged:
                status["code"] = 1

    _run(body)
    if status["code"]:
        typer.echo("error: the fit did not converge (see the table)", err=True)
        raise typer.Exit(status["code"])


def _expand(paths):
    files = []
    for p in paths:
        if p.is_dir():
            found = sorted(q for q in p.iterdir() if q.suffix.lower() in (".csv", ".binary", ".alta", ".dat"))
            if not found:
                raise UserError(f"{p}: folder has no measurement files (.csv, .binary, .alta, .dat)")
            files += found
        elif not p.exists():
            raise UserError(f"{p}: no such file")
        else:
            files.append(p)
    return files


def _bic_table(table, best) -> str:
    lines = ["model selection (lowest BIC wins):", f"  {'lobes':>5} {'diffuse':>8} {'params':>6} {'rel_rmse':>10} {'BIC':>14}"]
    for st, r in table:
        mark = "  <- kept" if r is best else ""
        lines.append(f"  {st.lobes:>5} {str(st.has_diffuse):>8} {r.stats['n_params']:>6} {r.stats['rel_rmse']:>10.4g} {r.stats['bic']:>14.6g}{mark}")
    return "\n".join(lines)


@app.command("sample")
def sample_cmd(
    fit_json: Path = typer.Argument(..., help="Fit-result JSON (a material TOML needs -o)."),
    data: Path = typer.Argument(..., help="The measurement the material was fitted to."),
    output: Optional[Path] = typer.Option(None, "-o", "--output", help="Write the JSON here (default: update FIT_JSON in place)."),
    as_json: bool = typer.Option(False, "--json", help="Print the resulting JSON instead of the table."),
    walkers: Optional[int] = typer.Option(None, "--walkers", help="Walkers (default max(2·ndim + 2, 32), even)."),
    steps: int = typer.Option(2000, "--steps", help="Steps per walker in all (also with --resume)."),
    burn: Optional[int] = typer.Option(None, "--burn", help="Steps discarded (default max(2 τ, steps/10), at most steps/2)."),
    thin: int = typer.Option(1, "--thin", help="Keep every THIN-th step."),
    seed: int = typer.Option(0, "--seed"),
    backend: Optional[Path] = typer.Option(None, "--backend", help="HDF5 file keeping the chain (emcee HDFBackend)."),
    resume: bool = typer.Option(False, "--resume", help="Continue the run stored in --backend up to --steps."),
    plot: Optional[Path] = typer.Option(None, "--plot", help="Folder for the corner and spectral-band PNGs."),
    param_out: Optional[str] = typer.Option(None, "--param-out", help=_PARAM_OUT_HELP),
):
    """Posterior sampling (emcee) of a fitted material: medians and 68 %/95 % intervals, written into the fit JSON."""

    def body():
        if resume and backend is None:
            raise UserError("--resume needs --backend")
        _setup_jax()
        import warnings

        from ._sample import ChainTooShortWarning
        from ._sample_io import format_uncertainty_table, sample_command_body

        meas = _read_data(data, param_out)
        with warnings.catch_warnings():
            warnings.simplefilter("ignore", ChainTooShortWarning)  # listed in the table and the JSON
            doc = sample_command_body(
                fit_json, meas, walkers, steps, burn, thin, seed, backend, resume, plot, output, progress=sys.stderr.isatty()
            )
        typer.echo(json.dumps(doc, indent=2) if as_json else format_uncertainty_table(doc, str(data)))
        typer.echo(f"wrote {output or fit_json}", err=True)

    _run(body)


@app.command()
def render(
    materials: List[Path] = typer.Argument(..., help="Material TOML or fit-result JSON files, one tile each."),
    output: Path = typer.Option(..., "-o", "--output", help="Output PNG."),
    size: int = typer.Option(256, "--size", help="Tile side in pixels."),
    shape: str = typer.Option("sphere", "--shape", help="sphere or vase."),
    compare: Optional[Path] = typer.Option(None, "--compare", help="Measurement file: show the one MATERIAL beside a rendering that uses the nearest measured BRDF."),
    labels: bool = typer.Option(True, "--labels/--no-labels", help="Write each material's name under its tile."),
    columns: Optional[int] = typer.Option(None, "--columns", help="Tiles per row (default: up to 6)."),
    step: float = typer.Option(5.0, "--step", help="Wavelength step of spectral rendering over 380–780 nm."),
    supersample: int = typer.Option(2, "--supersample", help="Samples per pixel along each axis (anti-aliasing)."),
    ambient: float = typer.Option(0.01, "--ambient", help="Ambient irradiance as a fraction of the two lights' (the paper's 1 %)."),
    exposure: str = typer.Option("reference", "--exposure", help="reference: the paper's scaling with a white reference object; tile: the tile alone."),
):
    """Render materials on spheres or vases under the paper's two lights (Figures 6–7) to a PNG."""

    def body():
        _setup_jax(float32=True)  # float32 is plenty for images
        from ._render_cli import render_command_body

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
    illuminant: str = typer.Option("D65", "--illuminant"),
    colourspace: str = typer.Option("sRGB", "--colourspace"),
    as_json: bool = typer.Option(False, "--json"),
):
    """The material's reflectance colour at normal incidence (or --angle): XYZ, xy, RGB, Lab, …"""

    def body():
        _setup_jax()
        from ._colour_report import colour_report

        mat = _load_material(material)
        rep = colour_report(mat, angle_deg=angle, illuminant=illuminant, colourspace=colourspace)
        if as_json:
            typer.echo(json.dumps(rep, indent=2, default=float))
        else:
            for k, v in rep.items():
                typer.echo(f"{k:>24}: {v}")

    _run(body)


def main():  # console-script entry point
    try:
        app()
    except KeyboardInterrupt:
        typer.echo("interrupted", err=True)
        sys.exit(130)


if __name__ == "__main__":
    main()
