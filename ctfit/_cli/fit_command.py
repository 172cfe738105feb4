"""The body of ``ctfit fit``: options and outputs checked first, then each file fitted (or files
fitted together by ``fit_batch``), reported, written; the exit status from the outcomes."""

from __future__ import annotations

import json
from pathlib import Path
from types import SimpleNamespace

from .inputs import check_param_out, load_material_file, read_data, setup_jax
from .messages import UserError, failure_line

__all__ = ["UNUSABLE", "check_fit_choices", "echo_wrote", "fit_command", "fit_exit_status", "fit_kwargs", "report_file", "structure_from_options"]


def structure_from_options(base, lobes: int, geometry, fresnel, diffuse):
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


def fit_command(o) -> int:
    """The ``fit`` command: options and outputs checked first, then every file; the exit status."""
    from .fit_cluster import TEXEL_SUFFIXES, fit_on_cluster, fit_texel_command
    from .._runtime import progress_enabled

    _check_fit_options(o)
    if len(o.data) == 1 and o.data[0].suffix.lower() in TEXEL_SUFFIXES:
        return fit_texel_command(o)
    files = _expand(o.data)
    setup_jax(o.float32)
    check_fit_choices(o)
    plan = _fit_plan(files, o)
    base = load_material_file(o.material) if o.material else None
    if o.workers is not None or o.scheduler is not None:
        outcomes = fit_on_cluster(files, o, base, plan, progress_enabled(o.quiet))
    else:
        outcomes = _fit_each(files, o, base, plan, progress_enabled(o.quiet))
    return fit_exit_status(outcomes)


def _check_fit_options(o) -> None:
    """Refuse bad option values before any work (typer's ``min=`` checks the counts)."""
    if o.geometry not in (None, "v-cavity", "smith", "smith-rational"):
        raise UserError(f"--geometry must be v-cavity, smith or smith-rational, got {o.geometry!r}")
    if o.fresnel not in (None, "effective-n", "conductor"):
        raise UserError(f"--fresnel must be effective-n or conductor, got {o.fresnel!r}")
    from .._model import MAX_LOBES

    if o.lobes != "auto" and not (o.lobes.isdigit() and 1 <= int(o.lobes) <= MAX_LOBES):
        raise UserError(f"--lobes must be 1..{MAX_LOBES} or 'auto', got {o.lobes!r}")
    check_param_out(o.param_out)
    if o.sample_ and o.thin > o.steps:
        raise UserError(f"--thin must be at most --steps ({o.steps}) to keep a draw, got {o.thin}")
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


def check_fit_choices(o) -> None:
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
                outcome = report_file(path, *got, o, plan[path], show)
            outcomes.append((outcome, str(path)))
        except (UserError, ValueError, OSError, KeyError) as e:
            if len(files) == 1:
                raise
            line = failure_line(path, e)
            echo(f"error: {line}", err=True)
            outcomes.append(("failed", line))
    return outcomes


UNUSABLE = "posterior not usable"
"""The outcome of a converged fit whose ``--sample`` posterior is not usable (exit status 1)."""


def fit_exit_status(outcomes: list[tuple[str, str]]) -> int:
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
    """Read, fit, print and write one file's results; its outcome (:func:`report_file`)."""
    meas = read_data(path, o.param_out)
    return report_file(path, meas, _fit_measurement(meas, o, base, show), o, t, show)


def _fit_together(files: list[Path], o, base) -> dict:
    """The first of ``files`` read — one at least, more while they hold fewer than
    ``SAMPLE_BUDGET`` samples in all, so memory stays bounded — and fitted by ``fit_batch``:
    path → (measurement, FitResult), or the exception that stopped that file (reading it, its
    start, or its fit)."""
    from .._fitting import SAMPLE_BUDGET, fit_batch, start_from_material

    st = structure_from_options(base.structure if base else None, int(o.lobes) if o.lobes != "auto" else 1, o.geometry, o.fresnel, o.diffuse)
    done: dict = {}
    ready, fixed, held = [], (), 0
    for path in files:
        if held >= SAMPLE_BUDGET:
            break
        try:
            meas = read_data(path, o.param_out)
            start, fixed = start_from_material(base, st, meas) if base else (None, ())
            ready.append((path, meas, start))
            held += len(meas)
        except (UserError, ValueError, OSError, KeyError) as e:
            done[path] = e
    fits = fit_batch([m for _, m, _ in ready], st, start=[s for _, _, s in ready], fixed=fixed, return_errors=True, **fit_kwargs(o))
    for (path, meas, _), res in zip(ready, fits):
        done[path] = res if isinstance(res, Exception) else (meas, res)
    return done


def report_file(path: Path, meas, res, o, t: SimpleNamespace, show: bool) -> str:
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
    echo_wrote(target, note)
    if t.plot is not None:
        from .._fitting import plot_fit

        plot_fit(res, meas, t.plot)
        echo_wrote(t.plot)
    return "not converged" if not res.converged else ("converged" if usable else UNUSABLE)


def _fit_measurement(meas, o, base, show: bool):
    """One fit: the structure of the options (or --material), or with --lobes auto the lowest BIC."""
    from .._fitting import fit as run_fit, start_from_material
    from .._runtime import echo

    kw = fit_kwargs(o)
    if o.lobes == "auto" and base is None:
        cands = [structure_from_options(None, j, o.geometry, o.fresnel, d) for j in (1, 2, 3) for d in (False, True)]
        res, table = _select_structure(meas, cands, kw, show)
        if not o.as_json:
            echo(_bic_table(table, res))
        return res
    lobes = int(o.lobes) if o.lobes != "auto" else 1
    st = structure_from_options(base.structure if base else None, lobes, o.geometry, o.fresnel, o.diffuse)
    start, fixed = start_from_material(base, st, meas) if base else (None, ())
    return run_fit(meas, st, start=start, fixed=fixed, **kw)


def fit_kwargs(o) -> dict:
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
    from .._sampling import ChainTooShortWarning, format_uncertainty_table
    from .sample_command import fit_sample_body

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


def echo_wrote(target, note: str | None = None) -> None:
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
