"""``ctfit fit`` on a Dask cluster (``--workers``, ``--scheduler``) and on a texel store: results
written as tasks complete, files already fitted from the same bytes and options kept, a summary."""

from __future__ import annotations

from pathlib import Path

from .fit_command import KEPT, check_fit_choices, echo_wrote, fit_kwargs, report_file, structure_choice, structure_from_options, texel_structure
from .inputs import read_data, setup_jax
from .messages import UserError, failure_line

__all__ = ["TEXEL_SUFFIXES", "fit_on_cluster", "fit_texel_command"]


def fit_on_cluster(files: list[Path], o, base, plan: dict, show: bool) -> tuple[list[tuple[str, str]], dict]:
    """--workers / --scheduler: files whose stored result was fitted from the same bytes with the
    same options are skipped; the others are fitted by ``fit_many`` on the cluster and each is
    reported and written as its task completes, with the hash of the bytes its worker parsed (a
    file rewritten since it was hashed here is not labelled with its old hash). Returns the
    outcomes and the inputs' hashes (for ``summary.json``, which the command writes beside the results).
    A file is hashed here only where a result of it is stored: the others' hashes are their workers'."""
    from .._fitting import fit_many, input_sha256
    from .._io import check_input_file
    from .._runtime import dask_client, echo

    options = _fit_options_record(o)
    hashes, outcomes, pending = {}, {}, []
    for path in files:
        try:
            if plan[path].json is not None and Path(plan[path].json).is_file():  # a stored result: kept if of the same bytes
                hashes[path] = input_sha256(path)
            else:  # hashed by its worker, from the read it fits: here only checked to be a file to read
                check_input_file(path, text=False)
        except OSError as e:
            outcomes[path] = ("failed", f"{path}: {e.strerror or e}")
            continue
        except ValueError as e:  # not a regular file (/dev/zero, a FIFO): never read
            outcomes[path] = ("failed", failure_line(path, e))
            continue
        kept = _kept_result(plan[path].json, hashes[path], options) if path in hashes else None
        if kept is None:
            pending.append(path)
        else:
            outcomes[path] = (kept, f"{path}{KEPT}")

    def done(i: int, got) -> None:
        path = pending[i]
        try:
            if isinstance(got, Exception):
                raise got
            hashes[path] = got.material.meta["input_sha256"]  # of the bytes the worker parsed, not those hashed here before
            got.material.meta.update(fit_options=options)
            meas = read_data(path, o.param_out) if plan[path].plot is not None else None
            outcomes[path] = (report_file(path, meas, got, o, plan[path], show), str(path))
        except (UserError, ValueError, OSError, KeyError, RuntimeError) as e:
            line = failure_line(path, e)
            echo(f"error: {line}", err=True)
            outcomes[path] = ("failed", line)
            hashes.pop(path, None)  # the summary hashes the file as it is then

    if pending:
        st = structure_from_options(base.structure if base else None, o)
        kw = fit_kwargs(o)
        with dask_client(workers=o.workers, scheduler=o.scheduler) as client:
            fit_many([str(p) for p in pending], st, client, material=base, param_out=o.param_out, return_errors=True, on_result=done,
                     progress=show, choice=structure_choice(o) if st is None else None, **kw)
    return [outcomes[p] for p in files], hashes


TEXEL_SUFFIXES = (".zarr", ".nc", ".h5", ".hdf5")


def fit_texel_command(o) -> int:
    """Texel data (``docs/formats.md``): every texel fitted on a Dask cluster (--workers, --scheduler,
    else one local worker per core), the maps written to the Zarr store -o as chunks complete
    (a re-run resumes), PNGs of the maps in the folder --plot. 0: every texel converged, 1: not."""
    from .._fitting import TEXEL_STATUS, fit_texel_maps, save_map_pngs
    from .._runtime import dask_client, echo, progress_enabled

    if o.output is None or o.output.suffix.lower() != ".zarr":
        raise UserError("texel data: give -o MAPS.zarr (the parameter maps are written there as a Zarr store)")
    if o.sample_ or o.material is not None or o.as_json or o.backend is not None:
        raise UserError("texel data: leave out --sample, --material, --json and --backend")
    _check_texel_outputs(o)
    st = texel_structure(o)
    setup_jax(o.float32)
    check_fit_choices(o)
    kw = fit_kwargs(o)
    with dask_client(workers=o.workers, scheduler=o.scheduler) as client:
        maps = fit_texel_maps(o.data[0], o.output, st, client, loss=kw["loss"], solver=kw["solver"], dtype=kw["dtype"], starts=kw["starts"],
                              max_steps=kw["max_steps"], progress=progress_enabled(o.quiet))
    with maps:
        import numpy as np

        converged = int(maps["converged"].sum())
        total = int(maps["converged"].size)
        status = maps["status"].values
        skipped = int(np.count_nonzero(status > 0))
        why = ", ".join(f"{int(np.count_nonzero(status == c))} {name.replace('_', ' ')}" for c, name in enumerate(TEXEL_STATUS) if c and (status == c).any())
        rel = maps["rel_rmse"].values
        echo(f"{o.data[0]}: {total} texels, {converged} converged, {total - converged - skipped} did not"
             + (f", {skipped} not fitted ({why}; map 'status')" if skipped else "")
             + (f"; median rel_rmse {float(np.nanmedian(rel)):.4g}" if np.isfinite(rel).any() else ""))
        echo_wrote(o.output)
        if o.plot is not None:
            for png in save_map_pngs(maps, o.plot):
                echo_wrote(png)
    return 0 if converged == total else 1


def _check_texel_outputs(o) -> None:
    """The maps store -o is not the input nor inside it, and the folder --plot can hold the PNGs."""
    import os

    from .._io import check_output_folder, same_file

    data, out = o.data[0], o.output
    if same_file(out, data):
        raise UserError(f"-o {out}: is the input {data}; write the maps to another store")
    inside = os.path.realpath(out).startswith(os.path.realpath(data).rstrip(os.sep) + os.sep)
    if inside or os.path.normpath(os.path.abspath(out)).startswith(os.path.normpath(os.path.abspath(data)) + os.sep):
        raise UserError(f"-o {out}: is inside the input {data}; write the maps to another store")
    if o.plot is not None:
        from .._fitting import map_picture_files, read_texel_geometry
        from .._io import check_rerun_plot

        dims = read_texel_geometry(data)[1]
        if dims != ("y", "x"):  # (refused by the pictures, after every texel was fitted and the maps written)
            raise UserError(f"--plot {o.plot}: {data} is not an image (values dims {(*dims, 'sample')}); pictures of the maps need values dims "
                            "(y, x, sample): leave out --plot")
        check_output_folder(o.plot, "--plot")
        for png in map_picture_files(o.plot):  # names ctfit chooses: only its own pictures are replaced
            check_rerun_plot(png)


def _fit_options_record(o) -> dict:
    """The options a stored result was fitted with (a re-run keeps it only if they are equal);
    ``material``: the SHA-256 of the --material file, and of the optical constants CSV it loads
    after a "+" (a changed table changes its fixed F0: a rerun kept the fits made with the old one)."""
    from .._fitting import input_sha256
    from .inputs import material_inputs

    material = "+".join(input_sha256(p) for p in material_inputs(o.material)) if o.material else None
    return dict(family=o.family, lobes=o.lobes, geometry=o.geometry, fresnel=o.fresnel, diffuse="none" if o.no_diffuse else o.diffuse, loss=o.loss,
                solver=o.solver, float32=o.float32, starts=o.starts, max_steps=o.max_steps, param_out=o.param_out, material=material)


def _kept_result(target, sha: str, options: dict) -> str | None:
    """'converged' or 'not converged' when ``target`` holds a fit of the same input and options
    that loads as a material, else None (fitted again: a result edited since, e.g. s = 2, is not kept)."""
    if target is None or not Path(target).is_file():
        return None
    from .._io import material_from_dict, read_json_or_none

    doc = read_json_or_none(target)  # nesting, huge numbers: not a result to keep
    fit = doc.get("fit") if isinstance(doc, dict) else None
    if not isinstance(fit, dict) or doc.get("input_sha256") != sha or doc.get("fit_options") != options:
        return None
    try:
        material_from_dict(doc)
    except (ValueError, KeyError, TypeError):
        return None
    return "converged" if fit.get("converged") is True else "not converged"
