"""The chain on disk: emcee's HDF5 backend, opened fresh or continued (``--backend``, ``--resume``).

A stored run carries a fingerprint of the data, loss and sampled coordinates; resuming it with
other ones is refused. Steps are written whole: a Ctrl-C in the ``ctfit`` command waits for the
one under way (:mod:`ctfit._io.interrupt`), so a resumed run equals an uninterrupted one.
"""

from __future__ import annotations

import functools
import hashlib
import json
import pathlib

import numpy as np

from .._io import deferred, note_resumable

__all__ = ["fingerprint", "open_run"]


def fingerprint(y, loss: str, labels: list[str]) -> str:
    h = hashlib.sha1()
    h.update(np.asarray(y).tobytes())
    h.update(loss.encode())
    h.update(json.dumps(labels).encode())
    return h.hexdigest()


def open_run(backend, *, resume: bool, overwrite: bool, steps: int, shape: tuple[int, int], fingerprint: str, labels: list[str], seed: int):
    """(emcee backend or None, steps already done): a fresh chain in ``backend``, or the stored
    one continued (``resume``), checked against this run's shape and fingerprint."""
    if backend is None:
        return None, 0
    path = pathlib.Path(backend)
    be = _open_backend(path, overwrite=overwrite)
    done = 0
    if resume and path.is_file() and path.stat().st_size and not be.initialized:  # another program's HDF5 file: never written into unasked
        raise ValueError(
            f"{path}: the HDF5 file holds no chain of ctfit (no group 'ctfit') to continue; name another file, or start a "
            "chain in this one (overwrite=True)"
        )
    if resume and path.exists() and be.initialized and be.iteration > 0:
        if be.shape != shape:
            raise ValueError(
                f"{path}: the stored run has (walkers, ndim) = {tuple(int(x) for x in be.shape)}, this one {tuple(int(x) for x in shape)}; "
                "pass the same walkers, or start again (overwrite=True)"
            )
        stored = _read_attr(path, "ctfit_fingerprint")
        if stored is not None and stored != fingerprint:
            raise ValueError(f"{path}: the stored run was sampled for other data, loss or parameters; start again (overwrite=True)")
        done = int(be.iteration)
        if done > steps:
            raise ValueError(f"{path}: the stored run already has {done} steps, more than steps={steps}")
    else:
        with deferred():  # a Ctrl-C in the ctfit command waits: no half-made file
            be.reset(*shape)
            _write_attrs(path, {"ctfit_fingerprint": fingerprint, "ctfit_labels": json.dumps(labels), "ctfit_seed": int(seed)})
    note_resumable(path)
    return be, done


def _h5py():
    """The ``h5py`` module (the "posterior" extra: one line naming it when missing)."""
    from .._runtime import need

    need("posterior", "a chain file (HDF5)")
    import h5py

    return h5py


def _open_backend(path: pathlib.Path, *, overwrite: bool):
    """emcee's HDF5 backend on ``path`` (checked by :func:`~ctfit._io.output_paths.check_backend`)."""
    h5py = _h5py()

    if overwrite and path.is_file() and not h5py.is_hdf5(path):
        with deferred(), h5py.File(path, "w"):  # start again in a file h5py cannot open (through a link, if one)
            pass
    return _whole_steps_backend()(str(path), name="ctfit")


@functools.cache
def _whole_steps_backend():
    import emcee

    class WholeStepsHDFBackend(emcee.backends.HDFBackend):
        """Steps written whole: a Ctrl-C in the ``ctfit`` command waits for the one under way."""

        def save_step(self, *args, **kwargs):
            with deferred():
                return super().save_step(*args, **kwargs)

        def grow(self, *args, **kwargs):
            with deferred():
                return super().grow(*args, **kwargs)

    return WholeStepsHDFBackend


def _write_attrs(path: pathlib.Path, attrs: dict) -> None:
    h5py = _h5py()

    with h5py.File(path, "a") as f:
        for k, v in attrs.items():
            f["ctfit"].attrs[k] = v


def _read_attr(path: pathlib.Path, key: str):
    h5py = _h5py()

    with h5py.File(path, "r") as f:
        v = f["ctfit"].attrs.get(key)
    return v.decode() if isinstance(v, bytes) else (None if v is None else str(v))
