"""The chain on disk: emcee's HDF5 backend, opened fresh or continued (``--backend``, ``--resume``).

A stored run carries a fingerprint of the data, loss and sampled coordinates; resuming it with
other ones is refused. Steps are written whole: a Ctrl-C in the ``ctfit`` command waits for the
one under way (:mod:`ctfit._io.interrupt`), so a resumed run equals an uninterrupted one.

A chain started again (``--overwrite``) in a file that holds something is written beside it, in
a temporary file of the same folder (:class:`NewChain`), and moved over it when the run ends: the
chain of before is lost only once the new one has its steps. A run that fails keeps the old file;
one interrupted with steps stored replaces it (then it can be resumed), one interrupted before
its first step keeps it; a killed process leaves the old file (and the temporary one, until a later write sweeps it).

One run at a time writes a chain file: :func:`~ctfit.sample` holds its lock (:mod:`ctfit._io.chain_lock`,
named after the file's real path) from its check to the run's end, the new chain's rename included.
"""

from __future__ import annotations

import functools
import hashlib
import json
import os
import pathlib

import jax
import numpy as np

from .._io import deferred, groups_beside_chain, note_resumable, on_interrupt, temporary_for

__all__ = ["NewChain", "fingerprint", "open_run"]


def fingerprint(problem, loss: str, labels: list[str], prior=()) -> str:
    """What a stored chain was sampled for, as a hash: every array of the ``problem`` (the values,
    their sigma column, the directions' geometry, the held parameters' values, the mask), the
    loss, the parameters' labels and the ``prior``. A chain resumed for anything else is refused:
    one whose sigma column was divided by 3 was continued under the other likelihood (R̂ 4·10¹⁵)."""
    h = hashlib.sha1()
    for leaf in jax.tree.leaves(problem):
        a = np.asarray(leaf)
        h.update(f"{a.dtype.str}{a.shape}".encode())
        h.update(np.ascontiguousarray(a).tobytes())
    h.update(loss.encode())
    h.update(json.dumps(labels).encode())
    h.update(repr(jax.tree.map(lambda a: np.asarray(a).tolist(), prior)).encode())
    return h.hexdigest()


def open_run(backend, *, resume: bool, overwrite: bool, steps: int, shape: tuple[int, int], fingerprint: str, labels: list[str], seed: int):
    """(emcee backend or None, steps already done, :class:`NewChain` or None): a fresh chain in
    ``backend``, or the stored one continued (``resume``), checked against this run's shape and
    fingerprint. With ``overwrite`` and a file there that holds something, the chain is written
    beside it (the :class:`NewChain` returned: ``commit()`` it when the run ends, ``abandon()``
    it when the run fails)."""
    if backend is None:
        return None, 0, None
    path = pathlib.Path(backend)
    new = NewChain(path) if overwrite and path.is_file() and path.stat().st_size else None
    try:
        return _opened(path, new, resume=resume, overwrite=overwrite, steps=steps, shape=shape, fingerprint=fingerprint, labels=labels, seed=seed)
    except BaseException:
        if new is not None:
            new.abandon()
        raise


def _opened(path: pathlib.Path, new, *, resume: bool, overwrite: bool, steps: int, shape: tuple[int, int], fingerprint: str, labels: list[str], seed: int):
    write_to = _through_link(path) if new is None else new.temp
    be = _open_backend(write_to, overwrite=overwrite and new is None)
    done = 0
    if resume and path.is_file() and path.stat().st_size and not be.initialized:  # another program's HDF5 file: never written into unasked
        others = groups_beside_chain(path)
        raise ValueError(
            f"{path}: the HDF5 file holds no chain of ctfit (no group 'ctfit') to continue; name another file"
            + (f" (it holds groups {others}, which a new chain would replace)" if others else ", or start a chain in this one (overwrite=True)")
        )
    if resume and path.exists() and be.initialized and _stored_steps(path) > 0:
        done = _continued(path, be, steps=steps, shape=shape, fingerprint=fingerprint, seed=seed)
    else:
        with deferred():  # a Ctrl-C in the ctfit command waits: no half-made file
            be.reset(*shape)
            _write_attrs(write_to, {"ctfit_fingerprint": fingerprint, "ctfit_labels": json.dumps(labels), "ctfit_seed": int(seed)})
    if new is None:
        note_resumable(path)
    else:
        new.started(be)
        note_resumable(lambda: path if new.committed or new.steps() else None)  # resumable once the new chain has a step (it then replaces the old)
    return be, done, new


def _continued(path: pathlib.Path, be, *, steps: int, shape: tuple[int, int], fingerprint: str, seed: int) -> int:
    """The steps of the stored run in ``path`` (checked by :func:`_stored_steps`), refused
    (``ValueError`` naming the file) where this run cannot continue it: other walkers, another
    set of sampled coordinates, data, loss or prior, another seed, or more steps than ``steps``."""
    if be.shape[1] != shape[1]:  # other coordinates: another structure, loss or set of fixed parameters
        raise ValueError(f"{path}: the stored run samples {int(be.shape[1])} coordinates, this one {int(shape[1])}: it was sampled for "
                         "another structure, loss or parameters; start again (overwrite=True)")
    if be.shape[0] != shape[0]:
        raise ValueError(f"{path}: the stored run has {int(be.shape[0])} walkers, this one {int(shape[0])}; pass walkers={int(be.shape[0])}, "
                         "or start again (overwrite=True)")
    stored = _read_attr(path, "ctfit_fingerprint")
    if stored is not None and stored != fingerprint:
        raise ValueError(f"{path}: the stored run was sampled for other data, loss or parameters; start again (overwrite=True)")
    started = _read_attr(path, "ctfit_seed")
    if started is not None and int(started) != int(seed):  # the chain goes on from its own random state: its seed is the one it began with
        raise ValueError(f"{path}: the stored run was started with seed={int(started)}, this one asks for seed={int(seed)}; pass seed="
                         f"{int(started)} to continue it, or start again (overwrite=True)")
    done = int(be.iteration)
    if done > steps:
        raise ValueError(f"{path}: the stored run already has {done} steps, more than steps={steps}")
    return done


_CHAIN_ATTRS = ("iteration", "nwalkers", "ndim", "has_blobs")  # emcee's HDFBackend.reset


def _stored_steps(path: pathlib.Path) -> int:
    """The steps stored in the group ``ctfit`` of ``path``; refused (``ValueError`` naming the file)
    where the group is not a whole chain of emcee's (another program's group of that name, a
    damaged file): HDF5's own message named no file ("can't locate attribute: 'iteration'")."""
    h5py = _h5py()

    with h5py.File(path, "r") as f:
        g = f["ctfit"]
        missing = [k for k in _CHAIN_ATTRS if not isinstance(g, h5py.Group) or k not in g.attrs]
        missing += [k for k in ("chain", "log_prob", "accepted") if not isinstance(g, h5py.Group) or not isinstance(g.get(k), h5py.Dataset)]
        steps = int(g.attrs["iteration"]) if not missing else 0
        if not missing and steps > 0:
            walkers, ndim = int(g.attrs["nwalkers"]), int(g.attrs["ndim"])
            if g["chain"].shape[:1] < (steps,) or g["chain"].shape[1:] != (walkers, ndim) or g["log_prob"].shape[:1] < (steps,):
                missing.append(f"{steps} steps of {walkers} walkers in 'chain' and 'log_prob'")
            if not any(k.startswith("random_state_") for k in g.attrs):
                missing.append("the random state")
    if missing:
        raise ValueError(f"{path}: the group 'ctfit' holds no chain that can be continued (no {', '.join(missing)}); restore the file from "
                         "a copy, or start again (overwrite=True)")
    return steps


class NewChain:
    """A chain started again in a file that holds one (or anything): written to a temporary file
    beside it, named and placed as :func:`~ctfit._io.atomic_write` places its own
    (:func:`~ctfit._io.temporary_for`: through a link, the file it names is replaced; the old
    file's permissions kept; a read-only file refused; one a killed run left is removed by a
    later write into the folder), and renamed over it by :meth:`commit`. A Ctrl-C in the
    ``ctfit`` command ends it by :meth:`stop`, and the line says how
    (:func:`~ctfit._io.interrupt.on_interrupt`)."""

    def __init__(self, path: pathlib.Path):
        self.path = path
        temp, self.target, self._mode = temporary_for(path)
        self.temp = pathlib.Path(temp)
        self._be = None
        self.committed = False
        self._withdraw = on_interrupt(lambda: self.stop() if self.temp.exists() else None)  # not once committed or abandoned

    def started(self, be) -> None:
        self._be = be

    def steps(self) -> int:
        """The steps the new chain has stored."""
        if self._be is None or not self.temp.is_file():
            return 0
        return int(self._be.iteration)

    def commit(self) -> None:
        """Move the new chain over the old file (one rename), the backend pointed at it."""
        if self._mode is not None:
            os.chmod(self.temp, self._mode)
        os.replace(self.temp, self.target)  # not deferred: the interrupted exit calls this holding the writes' lock
        self.committed = True
        self._withdraw()
        if self._be is not None:
            self._be.filename = self.target

    def abandon(self) -> None:
        """Remove the new chain; the old file stays as it was."""
        self._withdraw()
        self.temp.unlink(missing_ok=True)

    def stop(self) -> str:
        """End an interrupted run: with steps stored, the new chain replaces the file (it can be
        resumed); without, it is removed. Says which."""
        n = self.steps()
        if n:
            self.commit()
            return f"{self.path} now holds the new chain ({n} steps)"
        self.abandon()
        return f"{self.path} keeps what it held (the new chain had no step)"


def _through_link(path: pathlib.Path) -> pathlib.Path:
    """The file ``path`` names: a symbolic link's target, which the chain is written to (HDF5's
    create-or-open refused a link to a file not made yet: "unable to open file … File exists")."""
    return pathlib.Path(os.path.realpath(path)) if path.is_symlink() else path


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
