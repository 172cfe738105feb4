"""A spatially varying material fitted texel by texel across a Dask cluster, into parameter maps.

The input (``docs/formats.md``, "Texel data") is a Zarr store or a netCDF/HDF5 file that xarray
opens: ``values`` with dims (texel, sample) or (y, x, sample), and the shared goniometer
geometry as variables along ``sample`` (``theta_i``, ``phi_i``, ``theta_o``, ``phi_o`` in
degrees, ``band``) with ``wavelength_nm`` along ``band`` (or a ``channels`` attribute such as
"R,G,B"). :func:`fit_texel_maps` cuts the texels into chunks (whole rows of an image), and
each chunk is one task: the worker reads its rows of ``values`` from the store itself (no
values travel through the client) and fits them with :func:`~ctfit.fit_texels` in one compiled
program (the last chunk is padded to the same size), kept per worker process. The first chunk's
maps come back to the client, which creates the output Zarr store from their layout; every
other chunk's maps are written into their region of the store by the worker that fitted them
(so the store, like the input, must be reachable from every worker), and nothing but "done"
travels back. A chunk whose ``status`` is already written is skipped, so
a run that is killed resumes where it stopped, as long as the input is the same (its hash and
the fitting options are stored as attributes and checked).

The output maps, with the input's texel dims: ``m`` and ``weight`` (..., lobe), ``s``, ``F0``,
``Rd`` (..., band) where the structure has them, ``cost``, ``rmse``, ``rel_rmse``, ``steps``,
``converged`` (bool), ``status`` (int8, CF flags: 0 fitted; > 0 the texel's values could not be
fitted — :data:`~ctfit._fitting.texels.TEXEL_STATUS` says why — and its maps are NaN; -1 not
written yet). A texel that cannot be fitted does not stop the others; what would stop every
chunk (too few samples, unreadable data) is one :class:`TexelMapError`, raised by the client.
:func:`save_map_pngs` writes one PNG per map of an image (y, x).
"""

from __future__ import annotations

import hashlib
import json
import os
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np
from jax.typing import DTypeLike

from .._model import PARAMETER_AXES, PUBLIC_NAMES, Measurement, Structure

if TYPE_CHECKING:  # the cluster extra, imported where it is used
    import xarray as xr

__all__ = ["fit_texel_maps", "map_picture_files", "read_texel_geometry", "save_map_pngs", "MAP_PICTURES", "TexelMapError"]

_GEOMETRY = ("theta_i", "phi_i", "theta_o", "phi_o", "band")


class TexelMapError(ValueError):
    """A texel file or an output store that cannot be used; the message says why."""


def _open(path: str | os.PathLike[str]) -> Any:
    """The texel file as an xarray Dataset (every texel map starts here: the "cluster" extra)."""
    from .._runtime import need

    need("cluster", "texel maps")
    import xarray as xr

    path = os.fspath(path)
    engine = "zarr" if path.rstrip("/").endswith(".zarr") else "h5netcdf"
    try:
        backend: dict[str, Any] = {"consolidated": False} if engine == "zarr" else {}
        return xr.open_dataset(path, engine=engine, chunks=None, **backend)
    except (OSError, ValueError, KeyError) as e:
        raise TexelMapError(f"{path}: cannot be opened as texel data ({engine}): {e}") from None


def read_texel_geometry(path: str | os.PathLike[str]) -> tuple[Measurement, tuple[str, ...], tuple[int, ...]]:
    """The shared geometry of a texel file (a :class:`~ctfit.Measurement` without values), the
    texel dims (``("texel",)`` or ``("y", "x")``) and their sizes.

    >>> import numpy as np, xarray as xr, ctfit
    >>> theta = np.array([10.0, 30.0, 50.0])  # three samples, one band: the mirror direction
    >>> table = {"theta_i": theta, "phi_i": 0 * theta, "theta_o": theta, "phi_o": 180 + 0 * theta, "band": np.zeros(3, int)}
    >>> ds = xr.Dataset({"values": (("y", "x", "sample"), np.ones((2, 4, 3))), "wavelength_nm": ("band", [550.0]),
    ...                  **{k: ("sample", v) for k, v in table.items()}})
    >>> ds.to_netcdf("texels.nc", engine="h5netcdf")
    >>> data, dims, sizes = ctfit.read_texel_geometry("texels.nc")
    >>> data.theta_o, dims, sizes
    (array([10., 30., 50.]), ('y', 'x'), (2, 4))
    """
    with _open(path) as ds:
        missing = [k for k in ("values", *_GEOMETRY) if k not in ds.variables]
        if missing:
            raise TexelMapError(f"{path}: missing variable(s) {', '.join(missing)} (see docs/formats.md, 'Texel data')")
        dims = ds["values"].dims
        if dims[-1] != "sample" or len(dims) not in (2, 3):
            raise TexelMapError(f"{path}: values must have dims (texel, sample) or (y, x, sample), got {dims}")
        geo = {k: np.asarray(ds[k].values) for k in _GEOMETRY}
        channels = ds.attrs.get("channels")
        wavelength = np.asarray(ds["wavelength_nm"].values, dtype=float) if "wavelength_nm" in ds.variables else None
        if (wavelength is None) == (channels is None):
            raise TexelMapError(f"{path}: give the bands as a variable wavelength_nm or an attribute channels (not both)")
        sizes = tuple(int(ds.sizes[d]) for d in dims[:-1])
        empty = [f"{d} = 0" for d in dims if ds.sizes[d] == 0]
    if empty:
        raise TexelMapError(f"{path}: values has no texels or no samples ({', '.join(empty)})")
    band = geo["band"]
    if band.dtype.kind == "f" and np.all(np.isfinite(band)) and np.all(band == np.round(band)):
        band = band.astype(np.int64)  # whole numbers stored as floats
    try:  # the checks of every reader (Measurement): angles, band indices, wavelengths
        data = Measurement(*(geo[k] for k in _GEOMETRY[:4]), band=band, wavelength_nm=wavelength,
                           channels=None if channels is None else tuple(str(channels).split(",")), source=os.fspath(path))
    except (TypeError, ValueError) as e:
        raise TexelMapError(str(e).replace(f"Measurement {os.fspath(path)}: ", f"{os.fspath(path)}: variable ", 1)) from None
    return data, tuple(dims[:-1]), sizes


def _file_sha256(path: str | os.PathLike[str]) -> str:
    """SHA-256 of a file, or of a store's files (names and bytes, in sorted order)."""
    from .many import input_sha256

    p = Path(path)
    if p.is_file():
        return input_sha256(p)
    h = hashlib.sha256()
    for f in sorted(q for q in p.rglob("*") if q.is_file()):
        h.update(str(f.relative_to(p)).encode() + b"\0" + input_sha256(f).encode())
    return h.hexdigest()


def fit_texel_maps(
    path: str | os.PathLike[str],
    output: str | os.PathLike[str],
    structure: Structure | None = None,
    client: Any = None,
    *,
    workers: int | None = None,
    chunk: int = 4096,
    loss: str = "auto",
    solver: str = "lm",
    dtype: DTypeLike | None = None,
    starts: int = 3,
    max_steps: int = 256,
    progress: bool = False,
) -> xr.Dataset:
    """Fit every texel of the texel file ``path`` and write the parameter maps to the Zarr store ``output``.

    Chunks of about ``chunk`` texels (whole rows of an image) are fitted as Dask tasks on
    ``client`` (None: a :class:`~distributed.LocalCluster` of ``workers`` processes) and
    written as they complete; chunks already in ``output`` (same input, same options) are
    skipped. Returns the maps as an :class:`xarray.Dataset` (opened from ``output``).

    >>> import numpy as np, ctfit
    >>> def gold(m):
    ...     return ctfit.Material(ctfit.Structure(lobes=1, diffuse=None),
    ...                           ctfit.Params(m=np.array([m]), w=np.ones(1), f0=np.array([0.4, 0.9])),
    ...                           wavelength_nm=np.array([450.0, 650.0]))
    >>> import xarray as xr
    >>> geometry = ctfit.simulate(gold(0.2), n_pairs=300, seed=1)
    >>> values = np.stack([ctfit.evaluate(gold(m), geometry) for m in (0.1, 0.2, 0.3)])  # three texels
    >>> columns = {k: ("sample", getattr(geometry, k)) for k in ("theta_i", "phi_i", "theta_o", "phi_o", "band")}
    >>> xr.Dataset({"values": (("texel", "sample"), values), "wavelength_nm": ("band", geometry.wavelength_nm),
    ...             **columns}).to_zarr("texels.zarr", consolidated=False, mode="w")  # doctest: +ELLIPSIS
    <xarray.backends.zarr.ZarrStore object at ...>
    >>> maps = ctfit.fit_texel_maps("texels.zarr", "maps.zarr", gold(0.2).structure, workers=1)
    >>> np.round(maps["m"].values[:, 0], 4)
    array([0.1, 0.2, 0.3])
    """
    import jax.numpy as jnp

    from .._runtime import bar, dask_client

    dtype = jnp.float64 if dtype is None else dtype
    if chunk < 1:
        raise ValueError(f"chunk must be ≥ 1, got {chunk}")
    data, dims, sizes = read_texel_geometry(path)  # the "cluster" extra checked first (_open)
    import xarray as xr

    _check_geometry(data, structure, loss, dtype)
    options: dict[str, Any] = dict(loss=loss, solver=solver, dtype=dtype, starts=starts, max_steps=max_steps)
    record = json.dumps(dict(structure=repr(structure), **{k: (np.dtype(v).name if k == "dtype" else v) for k, v in options.items()}), sort_keys=True)
    stamp = dict(input=os.fspath(path), input_sha256=_file_sha256(path), fit_options=record)
    row = int(np.prod(sizes[1:])) if len(sizes) > 1 else 1
    rows = max(1, min(chunk // row, sizes[0]))  # an image smaller than a chunk is not padded to one
    spans = [(a, min(a + rows, sizes[0])) for a in range(0, sizes[0], rows)]
    x64 = np.dtype(dtype).itemsize == 8
    source = (os.fspath(path), os.path.abspath(path))  # workers may run in another folder
    store = os.path.abspath(output)
    task = dict(data=data, structure=structure, options=options, x64=x64, rows=rows, dims=dims)
    with dask_client(client, workers=workers) as cl:
        todo = _pending(output, stamp, spans)
        if todo is None:  # a new store: its layout from the first chunk's maps
            first = _checked(cl.submit(_fit_rows, source, spans[0], **task, pure=False).result())
            _create(output, first, dims, sizes, data, stamp, rows)
            _write(output, first, dims, spans[0])
            todo = spans[1:]
        futures = [cl.submit(_fit_rows, source, span, **task, output=store, pure=False) for span in todo]
        from distributed import as_completed

        for future in bar(as_completed(futures), desc="chunks", enabled=progress, total=len(futures)):
            _checked(future.result())  # a chunk's error, raised here
    return xr.open_zarr(output, consolidated=False)


def _check_geometry(data: Measurement, structure: Structure | None, loss: str, dtype: DTypeLike) -> None:
    """What would fail every chunk, said once by the client: too few samples for the structure's
    parameters, or the sigma loss (texels have no sigma)."""
    from .._model import Structure
    from .validate import check_fittable

    if loss == "sigma":
        raise TexelMapError("loss 'sigma' needs per-sample uncertainties, which texel values do not have; choose another loss")
    try:
        check_fittable(data.replace(brdf=np.ones(len(data))), structure or Structure(lobes=1, diffuse="F0/pi"), loss=loss, dtype=dtype)
    except ValueError as e:
        raise TexelMapError(str(e).replace("measure more", "every texel has that many; measure more")) from None


def _pending(output: str | os.PathLike[str], stamp: dict, spans: list) -> list | None:
    """The spans still to fit in an existing store (None: no store yet); a store of another input is refused."""
    import xarray as xr

    if not Path(output).exists():
        return None
    try:
        ds = xr.open_zarr(output, consolidated=False)
    except (OSError, ValueError, KeyError) as e:
        raise TexelMapError(f"{output}: exists and is not a texel-map store ({e}); choose another output") from None
    with ds:
        if any(ds.attrs.get(k) != v for k, v in stamp.items()):
            raise TexelMapError(f"{output}: holds maps of another input or other options; remove it or choose another output")
        if "status" not in ds:
            raise TexelMapError(f"{output}: holds maps without a 'status' map (an older ctfit's); remove it or choose another output")
        status = ds["status"]
        lead = status.dims[0]
        return [(a, b) for a, b in spans if (status.isel({lead: slice(a, b)}).values < 0).any()]


def _fit_rows(source: tuple[str, str], span: tuple[int, int], **task: Any) -> dict | None:
    """One task (:func:`_fit_span`); an error comes back as ``{"error": message}``, for the client
    to raise (raised here, the worker would print its traceback before the client's one line)."""
    try:
        return _fit_span(source, span, **task)
    except Exception as e:  # a corrupt chunk raises whatever its codec raises
        return {"error": f"{source[0]}, rows {span[0]}–{span[1] - 1}: {type(e).__name__}: {e}"}


def _checked(got: Any) -> Any:
    """A task's result, or its error raised as a :class:`TexelMapError`."""
    if isinstance(got, dict) and "error" in got:
        raise TexelMapError(got["error"])
    return got


def _fit_span(source: tuple[str, str], span: tuple[int, int], *, data: Measurement, structure: Structure | None, options: dict, x64: bool,
              rows: int,
              dims: tuple[str, ...], output: str | None = None) -> dict | None:
    """Rows ``span`` of ``values`` read from the store and fitted — padded to ``rows`` rows with
    copies of the last, so that every chunk runs one compiled program — and their maps written
    into ``output`` from this worker (None: returned, rows first)."""
    from .._runtime import prepare_worker
    from .texels import fit_texels

    prepare_worker(x64)
    shown, where = source
    with _open(where) as ds:
        block = np.asarray(ds["values"][span[0]: span[1]].values, dtype=float)
    lead = block.shape[:-1]
    flat = block.reshape(-1, block.shape[-1])
    n = len(flat)
    size = n // lead[0] * rows
    padded = np.concatenate([flat, np.broadcast_to(flat[-1:], (size - n, flat.shape[1]))])
    fits = fit_texels(data.replace(source=f"{shown}, rows {span[0]}–{span[1] - 1}"), padded, structure, chunk=size, **options)
    p, s = fits.params, fits.stats
    out = {"cost": s["cost"], "rmse": s["rmse"], "rel_rmse": s["rel_rmse"], "steps": s["steps"], "converged": s["converged"],
           "status": s["status"]}
    for key, name in PUBLIC_NAMES.items():
        value = getattr(p, key)
        if value is not None:
            out[name] = np.asarray(value)
    maps = {k: np.asarray(v)[:n].reshape(lead + np.asarray(v).shape[1:]) for k, v in out.items()}
    if output is None:
        return maps
    _write(output, maps, dims, span)
    return None


def _variables(maps: dict, dims: tuple[str, ...]) -> dict:
    return {k: ((*dims, PARAMETER_AXES[k]) if PARAMETER_AXES.get(k) and v.ndim > len(dims) else dims, v) for k, v in maps.items()}


def _create(output: str | os.PathLike[str], first: dict, dims: tuple[str, ...], sizes: tuple[int, ...], data: Measurement, stamp: dict, rows: int) -> None:
    """The output store: every map at full size (NaN / False until written), chunked like the tasks."""
    import dask.array as da
    import xarray as xr

    variables = {}
    for name, (vdims, v) in _variables(first, dims).items():
        shape = tuple(sizes) + v.shape[len(dims):]
        fill = np.nan if v.dtype.kind == "f" else (False if v.dtype.kind == "b" else -1)
        chunks = (rows,) + shape[1:]
        variables[name] = (vdims, da.full(shape, fill, dtype=v.dtype, chunks=chunks))
    ds = xr.Dataset(variables, attrs=stamp)
    from .texels import TEXEL_STATUS

    ds["status"].attrs.update(flag_values=list(range(-1, len(TEXEL_STATUS))), flag_meanings=" ".join(("not_written", *TEXEL_STATUS)))  # CF flags
    if "band" in ds.dims and data.wavelength_nm is not None:
        ds = ds.assign_coords(wavelength_nm=("band", np.asarray(data.wavelength_nm)))
    elif "band" in ds.dims:
        ds = ds.assign_coords(channel=("band", np.array(list(data.channels), dtype=object)))  # variable-length: Zarr v3 has no fixed-width text
    ds.to_zarr(output, mode="w-", compute=True, consolidated=False)


def _write(output: str | os.PathLike[str], maps: dict, dims: tuple[str, ...], span: tuple[int, int]) -> None:
    """One chunk's maps into their region of the store (``status`` last: it marks the chunk done)."""
    import xarray as xr

    variables = _variables(maps, dims)
    rest = {k: v for k, v in variables.items() if k != "status"}
    region = {dims[0]: slice(*span)}
    xr.Dataset(rest).to_zarr(output, region=region, consolidated=False)
    xr.Dataset({"status": variables["status"]}).to_zarr(output, region=region, consolidated=False)


MAP_PICTURES = ("m", "weight", "s", "F0", "n", "k", "Rd", "cost", "rel_rmse", "converged", "status")
"""The maps :func:`save_map_pngs` draws, each ``NAME.png`` (or ``NAME_J.png``, per lobe or band)."""


def map_picture_files(folder: str | os.PathLike[str]) -> list[Path]:
    """The files in ``folder`` with a name :func:`save_map_pngs` may write (``NAME.png``, ``NAME_J.png``
    of :data:`MAP_PICTURES`): what a run there would replace."""
    import re

    folder = Path(folder)
    pattern = re.compile(rf"({'|'.join(map(re.escape, MAP_PICTURES))})(_\d+)?\.png")
    return sorted(p for p in folder.iterdir() if pattern.fullmatch(p.name)) if folder.is_dir() else []


def save_map_pngs(maps: Any, folder: str | os.PathLike[str]) -> list[Path]:
    """One PNG per map of an image's maps (dims y, x): per lobe (m, weight), per band (F0, Rd),
    and s, cost, rel_rmse, converged; each scaled to its own range (the PNG's name says which)."""
    from .._io import atomic_save, plot_metadata
    from .._runtime import matplotlib_config_fallback, need

    need("plots", "pictures of parameter maps")
    matplotlib_config_fallback()
    import matplotlib

    matplotlib.use("Agg", force=False)
    import matplotlib.pyplot as plt

    folder = Path(folder)
    folder.mkdir(parents=True, exist_ok=True)
    written = []
    for name in MAP_PICTURES:
        if name not in maps.variables:
            continue
        var = maps[name]
        if var.dims[:2] != ("y", "x"):
            raise TexelMapError(f"maps of texels without an image layout (dims {var.dims}) have no PNG; give values dims (y, x, sample)")
        extra = var.dims[2] if var.ndim == 3 else None
        for j in range(var.sizes[extra] if extra else 1):
            image = np.asarray((var.isel({extra: j}) if extra else var).values, dtype=float)
            stem = f"{name}_{j}" if extra else name
            fig, ax = plt.subplots(figsize=(4, 3.4))
            shown = ax.imshow(image, cmap="viridis" if name != "cost" else "magma", interpolation="nearest")
            fig.colorbar(shown, ax=ax)
            ax.set_title(stem)
            ax.set_axis_off()
            atomic_save(folder / f"{stem}.png", lambda b, f=fig: f.savefig(b, format="png", dpi=100, metadata=plot_metadata("png")))
            plt.close(fig)
            written.append(folder / f"{stem}.png")
    return written
