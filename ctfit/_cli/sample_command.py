"""The bodies of ``ctfit sample`` and ``ctfit fit --sample``: sample, write the ``uncertainty`` section.

The typer commands in :mod:`ctfit._cli.commands` parse the options and call :func:`sample_command_body`
or :func:`fit_sample_body`; this module holds no CLI framework code, and imports nothing heavy
at import time.

The ``uncertainty`` section (``docs/uncertainty.md``) is :meth:`ctfit.SampleResult.to_dict`,
with ``plots`` (the PNGs written, when asked) and ``idata`` (the ArviZ netCDF file, when asked).
"""

from __future__ import annotations

import os
import pathlib

__all__ = ["check_default_output", "check_posterior_plots", "default_output", "fit_sample_body", "result_stem", "run_longer", "sample_command_body"]


def _read_data(data):
    """The measurement: ``data`` itself when it is one, else the file it names."""
    from .._model import Measurement

    if isinstance(data, Measurement):
        return data
    from .._io import read_measurement

    return read_measurement(data)


POSTERIOR_PLOTS = ("corner", "spectra")
"""The posterior's plots, ``<stem>.<kind>.png`` in the plot folder."""


def check_posterior_plots(plot_dir, stem: str) -> None:
    """Refuse, before any work, a file of the user's where the posterior's plots would go
    (names ``ctfit`` chooses itself: only its own plots are replaced, :func:`~ctfit._io.output_paths.check_rerun_plot`)."""
    from .._io import check_rerun_plot

    for kind in POSTERIOR_PLOTS:
        check_rerun_plot(pathlib.Path(plot_dir) / f"{stem}.{kind}.png")


def _plots(result, plot_dir, stem: str) -> list[str]:
    """``<stem>.corner.png`` and ``<stem>.spectra.png`` in ``plot_dir``, those that have something to show."""
    from .._sampling import plot_corner, plot_spectra

    plot_dir = pathlib.Path(plot_dir)
    plot_dir.mkdir(parents=True, exist_ok=True)
    out = []
    for plot, kind in zip((plot_corner, plot_spectra), POSTERIOR_PLOTS):
        try:
            out.append(str(plot(result, plot_dir / f"{stem}.{kind}.png")))
        except ValueError:  # nothing to plot
            pass
    return out


def _check_fitted_loss(material, fit_json: pathlib.Path) -> None:
    """The file's ``fit.loss``, checked before any work (:func:`~ctfit._sampling.start.check_fitted_loss`), the file named."""
    from .._sampling import check_fitted_loss

    try:
        check_fitted_loss(material)
    except ValueError as e:
        raise ValueError(f"{fit_json}: {e}") from None


def result_stem(path: pathlib.Path) -> str:
    """The file name without ``.json`` or ``.toml`` (the plots' names start with it)."""
    name = path.name
    for suffix in (".json", ".toml"):
        if name.endswith(suffix):
            name = name[: -len(suffix)]
    return name


def default_output(fit_json) -> pathlib.Path:
    """Where ``ctfit sample FIT`` writes without ``-o``: ``<stem>.posterior.json`` beside FIT
    (``copper.fit.json`` → ``copper.fit.posterior.json``), never FIT itself."""
    fit_json = pathlib.Path(fit_json)
    return fit_json.with_name(f"{result_stem(fit_json)}.posterior.json")


def check_default_output(target) -> None:
    """The posterior's file without ``-o`` (:func:`default_output`), a name ``ctfit`` chooses: refused
    where it is a link or a file that is not a posterior ctfit wrote (:func:`~ctfit._io.output_paths.check_own_name`)."""
    from .._io import check_own_name, is_posterior

    check_own_name(target, is_posterior, "a posterior of ctfit", "name the result with -o")


def run_longer(doc: dict, *, backend=None) -> str | None:
    """The command-line hint for a chain that has not mixed (``uncertainty.checks.mixing``):
    the ``--steps`` that would do, and how to keep the chain run so far; None when it mixed."""
    mixing = doc.get("uncertainty", {}).get("checks", {}).get("mixing", {})
    need = mixing.get("steps_needed")
    if not mixing.get("flag") or need is None:
        return None
    keep = f"--backend {backend} --resume continues this chain" if backend is not None else "with --backend FILE, a later --resume continues the chain"
    return f"run longer: --steps {need} or more ({keep})"


def _write_idata(result, path) -> str:
    """The chain as ArviZ netCDF (``az.from_netcdf(path)``), written atomically."""
    import tempfile

    from .._io import atomic_write

    with tempfile.TemporaryDirectory() as folder:
        tmp = pathlib.Path(folder) / "run.nc"
        result.to_inference_data().to_netcdf(str(tmp))
        atomic_write(path, [tmp.read_bytes()])
    return str(path)


def _uncertainty(target, data, *, plot_dir, stem: str, idata=None, backend=None, **options) -> dict:
    """Sample ``target`` on ``data`` (``options``: those of :func:`ctfit.sample`) and return the
    ``uncertainty`` section, with the plots written to ``plot_dir`` and the chain to ``idata``
    when given."""
    from .._sampling import sample

    result = sample(target, data, backend=None if backend is None else str(backend), **options)
    section = result.to_dict()
    if plot_dir is not None:
        section["plots"] = _plots(result, plot_dir, stem)
    if idata is not None:
        section["idata"] = _write_idata(result, idata)
    return section


def sample_command_body(
    fit_json,
    data,
    walkers: int | None = None,
    steps: int = 2000,
    burn: int | None = None,
    thin: int = 1,
    seed: int = 0,
    backend=None,
    resume: bool = False,
    plot_dir=None,
    output=None,
    *,
    progress: bool = False,
    priors: dict | None = None,
    overwrite: bool = False,
    loss: str | None = None,
    idata=None,
) -> dict:
    """``ctfit sample FIT.json DATA``: sample, write the fit JSON with its ``uncertainty`` section.

    Reads the material (fit JSON or TOML) and the measurement (a path, or a
    :class:`~ctfit.Measurement` already read), samples (the loss recorded in
    the file's ``fit`` section, else sigma/relative), writes ``output`` (default:
    :func:`default_output`, beside the input, which is never written unless ``output`` names it)
    atomically — every key of the input kept, ``uncertainty`` replaced — and, with
    ``plot_dir``, ``<stem>.corner.png`` and ``<stem>.spectra.png``.
    ``overwrite``: start a new chain in an existing ``backend`` (see :func:`ctfit.sample`);
    ``loss``: the likelihood's residual weighting (another than the file's fits again first);
    ``idata``: also write the chain as ArviZ netCDF there. Returns the document written (JSON-ready).
    """
    from .._io import check_output, check_output_folder, load_material, material_to_dict, save_material_json

    fit_json = pathlib.Path(fit_json)
    material = load_material(fit_json)
    if loss is None:
        _check_fitted_loss(material, fit_json)
    target = pathlib.Path(output) if output is not None else default_output(fit_json)
    inputs = ([data] if isinstance(data, (str, os.PathLike)) else []) + ([] if output is not None else [fit_json])
    check_output(target, inputs, option="-o" if output is not None else "")
    if output is None:
        check_default_output(target)
    if plot_dir is not None:
        check_output_folder(plot_dir, "--plot")
        check_posterior_plots(plot_dir, result_stem(target))
    extra = {
        "uncertainty": _uncertainty(
            material, _read_data(data), walkers=walkers, steps=steps, burn=burn, thin=thin, seed=seed, backend=backend,
            resume=resume, overwrite=overwrite, progress=progress, priors=priors, loss=loss, plot_dir=plot_dir,
            stem=result_stem(target), idata=idata,
        )  # fmt: skip
    }
    save_material_json(material, target, extra=extra)
    return material_to_dict(material, extra=extra)


def fit_sample_body(fit_result, data, *, plot_dir=None, output=None, plot_stem: str = "fit", own_of=None, **options) -> dict:
    """``ctfit fit DATA --sample``: sample a fresh :class:`~ctfit.FitResult` on its measurement.

    Returns the fit-result document with ``fit`` and ``uncertainty`` sections; writes it
    atomically to ``output`` when given (``own_of``: the input's path, in a results folder, where
    ``output`` is written over nothing or that input's earlier result only, checked at the write:
    :func:`~ctfit._io.write_own_result`), and the plots to ``plot_dir`` (named after ``output``,
    else ``plot_stem``). ``options``: those of :func:`ctfit.sample` (``walkers``, ``steps``,
    ``backend``, ``resume``, ``overwrite``, ``progress``, ...).
    """
    from .._fitting import fit_result_to_dict
    from .._io import material_json, material_to_dict, save_material_json, write_own_result

    stem = result_stem(pathlib.Path(output)) if output is not None else plot_stem
    section = _uncertainty(fit_result, data, plot_dir=plot_dir, stem=stem, **options)
    extra = {**fit_result_to_dict(fit_result, material_keys=False), "uncertainty": section}
    if output is not None and own_of is not None:
        write_own_result(output, [material_json(material_to_dict(fit_result.material, extra))], own_of)
    elif output is not None:
        save_material_json(fit_result.material, output, extra=extra)
    return material_to_dict(fit_result.material, extra=extra)
