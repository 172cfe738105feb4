"""Where results may be written: checked before any work, so that no command loses a user's file.

The commands call these before reading data or starting JAX: an output that is one of the
inputs, a read-only file, a folder that cannot be created or written, or an HDF5 chain that
would be wiped is refused with an :class:`OutputError` naming the user's path and the option.
The writing itself is :func:`ctfit._io.files.atomic_write`.
"""

from __future__ import annotations

import contextlib
import errno
import functools
import hashlib
import os
import re
import stat
from pathlib import Path

from .._model import valid_name
from .chain_lock import hold_chain
from .files import atomic_write, replace_links_in, writes_in_place
from .untrusted import input_sha256, quote, read_json_or_none

__all__ = [
    "OutputError",
    "check_output",
    "check_output_folder",
    "check_backend",
    "InputFiles",
    "same_file",
    "result_targets",
    "check_rerun_target",
    "write_own_result",
    "groups_beside_chain",
    "check_rerun_plot",
    "check_distinct",
    "check_own_name",
    "unconverged_target",
    "unconverged_name",
    "is_fit_result",
    "is_posterior",
    "PLOT_SOFTWARE",
    "plot_metadata",
]


class OutputError(ValueError):
    """An output path that would lose or damage a file, or cannot be written; the message names it."""


def _identity(p) -> frozenset:
    """What makes two paths the same file: the physical path (links followed; ``..`` after a
    folder that does not exist yet, as the system will take it once the folder is made), the
    lexical one (``os.path.normpath``), and the device and inode of whichever exists. Two paths
    are the same file when they share any of these."""
    found: set[tuple[str | int, ...]] = set()
    for q in {os.path.realpath(p), os.path.normpath(os.path.abspath(p))}:
        found.add(("path", q))
        try:
            st = os.stat(q)
            found.add(("inode", st.st_dev, st.st_ino))
        except OSError:
            pass
    return frozenset(found)


class InputFiles:
    """A run's input files, each :func:`_identity` looked up once (inputs are read, never
    written): ``which(path)`` is the first input that is the same file as ``path``, in time
    independent of their number, so checking one output per input of a database is linear.

    >>> InputFiles(["a.csv", "b.csv"]).which("./b.csv")
    'b.csv'
    """

    def __init__(self, paths=()):
        self._first: dict = {}
        for i, p in enumerate(paths):
            if p is not None:
                for atom in _identity(p):
                    self._first.setdefault(atom, (i, p))

    def which(self, path):
        """The first input that is the same file as ``path``, or None."""
        found = [self._first[a] for a in _identity(path) if a in self._first]
        return min(found, key=lambda f: f[0])[1] if found else None


def same_file(a, b) -> bool:
    """Whether the paths ``a`` and ``b`` name one file (:func:`_identity`: links, hard links, ``..``)."""
    return bool(_identity(a) & _identity(b))


def _loops(path: Path) -> bool:
    """Whether ``path`` is a symbolic link that leads (through others, maybe) to itself."""
    try:
        os.stat(path)
    except OSError as e:
        return e.errno == errno.ELOOP
    return False


def broken_link(path) -> str | None:
    """Why ``path``, a symbolic link, leads to no file ("is a symbolic link that leads to itself",
    or "… to TARGET, which does not exist"); None when it is no link or leads to a file."""
    path = Path(path)
    if not path.is_symlink() or os.path.exists(path):
        return None
    if _loops(path):
        return "is a symbolic link that leads to itself"
    return f"is a symbolic link to {os.readlink(path)}, which does not exist"


def _name_max(folder: Path) -> int:
    """The longest file name, in bytes, that the file system of ``folder`` (or its nearest existing parent) takes."""
    for p in (folder, *folder.parents):
        try:
            return os.pathconf(p, "PC_NAME_MAX")
        except (OSError, ValueError):
            continue
    return 255


def _at(option: str, path) -> str:
    return f"{option} {path}" if option else str(path)


def _folder_ok(folder: Path, shown: Path, option: str) -> None:
    """Create ``folder`` if needed and check that files can be made in it (``shown``: the user's path)."""
    blocker = next((p for p in (folder, *folder.parents) if p.exists() or p.is_symlink()), None)
    if blocker is not None and not blocker.is_dir():
        raise OutputError(f"{_at(option, shown)}: {blocker} is a file, not a folder")
    try:
        folder.mkdir(parents=True, exist_ok=True)
    except OSError as e:
        raise OutputError(f"{_at(option, shown)}: cannot create the folder {folder} ({e.strerror})") from None
    mode = folder.stat().st_mode
    if not os.access(folder, os.W_OK | os.X_OK) or not mode & 0o222:  # no write bit: refused even for root
        raise OutputError(f"{_at(option, shown)}: the folder {folder} is not writable (mode {stat.filemode(mode)})")


def _writable_file(path: Path, shown: Path, option: str) -> None:
    """Refuse an existing regular file without write permission.

    A file whose mode has no write bit (``chmod a-w``) is refused even for root, who could
    write it anyway: the mode says the user wants it kept.
    """
    st = path.stat()
    if not st.st_mode & (stat.S_IWUSR | stat.S_IWGRP | stat.S_IWOTH) or not os.access(path, os.W_OK):
        raise OutputError(
            f"{_at(option, shown)}: the file is read-only (mode {stat.filemode(st.st_mode)}); "
            "make it writable (chmod u+w) or choose another name"
        )


def check_output(path, inputs=(), *, option: str = "-o", chosen: bool = False) -> Path:
    """Check, before any work, that a result may be written to the file ``path``; return it.

    Refused (:class:`OutputError`): ``path`` is the same file as one of ``inputs``; it is a
    folder; it exists and is read-only (no write bit in its mode, even for root, or not writable
    by this user); its folder cannot be created or written. Missing parent folders are created.
    Messages start with ``option`` and the path (``option=""``: the path alone).
    ``inputs``: paths, or an :class:`InputFiles` made once for the checks of many outputs.
    The same file means the same physical file, whatever the spelling: links, hard links, and
    ``..`` after folders that do not exist yet. A name longer than the file system takes is
    refused. A symbolic link is checked at its target (the write goes through it); ``chosen``
    (a name ``ctfit`` chose in an output folder): a symbolic link there is refused. A device or
    FIFO (``/dev/null``, ``/dev/stdout``) is accepted as it is.
    """
    path = Path(path)
    if writes_in_place(path):  # nothing there to lose (a terminal may be both input and output)
        return path
    limit = _name_max(path.parent)
    if len(os.fsencode(path.name)) > limit:
        raise OutputError(f"{_at(option, path)}: the file name is {len(os.fsencode(path.name))} bytes long; the file system takes at most {limit}")
    inp = (inputs if isinstance(inputs, InputFiles) else InputFiles(inputs)).which(path)
    if inp is not None:
        raise OutputError(f"{_at(option, path)}: is the input {inp}; write the result to another file")
    if path.is_symlink() and _loops(path):
        raise OutputError(f"{_at(option, path)}: is a symbolic link that leads to itself; remove it or choose another name")
    if path.is_dir():
        raise OutputError(f"{_at(option, path)}: is a folder; give a file name")
    if chosen and path.is_symlink():
        raise OutputError(
            f"{_at(option, path.parent)}: {path} is a symbolic link (to {os.readlink(path)}); results are not written "
            "through links in an output folder: remove the link or choose another folder"
        )
    target = Path(os.path.realpath(path)) if path.is_symlink() else path  # written through: check where it leads
    if target.exists():
        _writable_file(target, path, option)
    _folder_ok(target.parent, path, option)
    return path


def check_output_folder(path, option: str = "-o") -> Path:
    """Check, before any work, that results may be written into the folder ``path`` (created if
    missing). Atomic writes into it replace a symbolic link rather than write through it
    (:func:`ctfit._io.files.replace_links_in`): the names there are ``ctfit``'s."""
    path = Path(path)
    if path.exists() and not path.is_dir():
        raise OutputError(f"{_at(option, path)}: is a file, not a folder")
    _folder_ok(path, path, option)
    replace_links_in(path)
    return path


def check_backend(path, inputs=(), *, resume: bool, overwrite: bool, flags=("--resume", "--overwrite"), option: str = "--backend",
                  chosen: bool = False, hold: contextlib.ExitStack | None = None) -> Path:
    """Check an HDF5 chain file before sampling: a stored chain is never wiped unasked, nor
    written by two runs at once.

    An existing, non-empty ``path`` needs ``resume`` (continue the chain there; refused when
    the file is not HDF5) or ``overwrite`` (start again); ``flags`` name the two in messages
    (the command's options, or the library's ``resume=True`` / ``overwrite=True``). A file that
    another run is writing is refused before it is read (:mod:`~ctfit._io.chain_lock`): its
    lock is taken into ``hold``, and kept until that closes (the run's end); without ``hold``
    it is only checked that no run holds it now. The other checks are :func:`check_output`'s.
    """
    path = Path(path)
    if resume and overwrite:
        raise OutputError(f"{flags[0]} and {flags[1]} exclude each other: continue the stored chain, or start again")
    check_output(path, inputs, option=option, chosen=chosen)
    _lock_chain(path, option, hold)
    if not path.is_file() or path.stat().st_size == 0:
        return path
    if overwrite:
        _check_only_chains(path, option)
        return path
    if not resume:
        raise OutputError(
            f"{_at(option, path)}: the file exists; continue the chain stored there with {flags[0]}, "
            f"or start again (replacing it) with {flags[1]}"
        )
    import h5py  # the "posterior" extra: its callers (sample, the CLI) checked it is installed

    if not h5py.is_hdf5(path):
        raise OutputError(f"{_at(option, path)}: is not an HDF5 file, so it holds no chain to continue")
    _check_readable(path, option, "it holds no chain to continue")
    _check_one_name(path, option)
    return path


def _check_one_name(path: Path, option: str) -> None:
    """Refuse (:class:`OutputError`) to continue a chain in a file of several names (hard links):
    a continued chain is written in place, so the file would change under every name (a backup
    snapshot made with hard links, say), and the lock is taken by name (:mod:`~ctfit._io.chain_lock`):
    a run through another name would write the file at the same time."""
    links = path.stat().st_nlink
    if links > 1:
        raise OutputError(f"{_at(option, path)}: the file has {links} names (hard links); a continued chain is written in place, which would change "
                          "it under every name, and a run through another name would not be kept out: continue a copy of it (cp makes one)")


def _check_readable(path: Path, option: str, so: str) -> list[str]:
    """The names at the top of an HDF5 file; refused (:class:`OutputError`, naming the file) where
    HDF5 cannot open it: a truncated or damaged one (a copy cut short, a full disk). HDF5's own
    message named neither the file nor the option ("Unable to synchronously open file (truncated
    file: eof = 20000, …)"). ``so``: what that means for the run."""
    import h5py

    try:
        with h5py.File(path, "r") as f:
            return list(f.keys())
    except OSError as e:
        raise OutputError(f"{_at(option, path)}: HDF5 cannot read the file ({_hdf5_reason(e)}), so {so}; restore it from a copy, or move it "
                          "away and start again") from None


def _hdf5_reason(err: OSError) -> str:
    """HDF5's reason in a few words: "truncated: 20,000 of 4,596,888 bytes", or what it says in brackets."""
    text = str(err)
    cut = re.search(r"truncated file: eof = (\d+).*stored_eof = (\d+)", text)
    if cut:
        return f"truncated: {int(cut[1]):,} of {int(cut[2]):,} bytes"
    inner = re.search(r"\((.*)\)\s*$", text)
    return inner[1] if inner else text


def _lock_chain(path: Path, option: str, hold: contextlib.ExitStack | None) -> None:
    """Take the lock of the chain file ``path`` into ``hold`` (None: take it and give it back);
    refused (:class:`OutputError`) where another run holds it."""
    try:
        if hold is None:
            with hold_chain(path):
                return
        hold.enter_context(hold_chain(path))
    except BlockingIOError:
        raise OutputError(f"{_at(option, path)}: another ctfit run is writing this chain file; wait for it to end, or name another file") from None


def _check_only_chains(path: Path, option: str) -> None:
    """Refuse (:class:`OutputError`) to start a chain again in a file that holds more than ctfit's
    chain: the new chain replaces the whole file (one rename), and with it the user's other data
    (a lab's HDF5 file lost its calibration group so), or a file that is not HDF5 at all."""
    import h5py

    if not h5py.is_hdf5(path):
        raise OutputError(f"{_at(option, path)}: is not an HDF5 file; a new chain replaces only a file of ctfit's chain: name another file")
    listed = _beside_chain(_check_readable(path, option, "what it holds cannot be checked before a new chain replaces it"))
    if listed:
        raise OutputError(f"{_at(option, path)}: the HDF5 file holds {listed} beside ctfit's chain, which a new chain would replace (the "
                          "whole file is written anew): name another file")


def groups_beside_chain(path) -> str:
    """The names of what an HDF5 file holds beside ctfit's group ``ctfit`` ("'calibration', 'raw'",
    five at most), or ""."""
    import h5py

    with h5py.File(path, "r") as f:
        return _beside_chain(list(f.keys()))


def _beside_chain(keys: list[str]) -> str:
    others = [k for k in keys if k != "ctfit"]
    return ", ".join(repr(k) for k in others[:5]) + (", …" if len(others) > 5 else "")


def _names(paths: list[Path]) -> list[str]:
    """Distinct file stems: files of one folder that share a stem get their suffix after it (x.csv,
    x.dat → x-csv, x-dat); shared names in other folders get their parent folders' names in front
    (a/x, b/x → a-x, b-x), only as far as the folders differ; a number where nothing tells them
    apart (x.csv, X.CSV where case counts). A file's name so depends on the files beside it and of
    its name, not on the whole set: one taken away or added elsewhere renames none."""
    parents = [Path(os.path.abspath(p)).parent for p in paths]
    parts = [q.parts[1:] for q in parents]
    beside: dict[tuple, int] = {}
    for q, p in zip(parents, paths):
        beside[(q, p.stem.casefold())] = beside.get((q, p.stem.casefold()), 0) + 1
    stems = [p.stem + (f"-{p.suffix[1:]}" if p.suffix and beside[(q, p.stem.casefold())] > 1 else "") for q, p in zip(parents, paths)]
    level = [0] * len(paths)

    def name(i: int) -> str:
        k = min(level[i], len(parts[i]))
        return "-".join([*parts[i][len(parts[i]) - k :], stems[i]])

    while True:
        seen: dict[str, list[int]] = {}
        for i in range(len(paths)):
            seen.setdefault(name(i).casefold(), []).append(i)
        clashes = [g for g in seen.values() if len(g) > 1]
        grow = [i for g in clashes for i in g if level[i] < len(parts[i]) and any(parents[j] != parents[i] for j in g)]
        if not grow:
            break
        for i in grow:
            level[i] += 1
    out = [name(i) for i in range(len(paths))]
    used = {n.casefold() for n in out}
    count: dict[str, int] = {}
    for i, n in enumerate(out):
        key = n.casefold()
        count[key] = count.get(key, 0) + 1
        if count[key] > 1:  # the same folders all the way up: number the later ones
            j = count[key]
            while f"{n}-{j}".casefold() in used:
                j += 1
            out[i] = f"{n}-{j}"
            used.add(out[i].casefold())
    return out


def result_targets(inputs, folder, suffix: str) -> dict[Path, Path]:
    """One result file in ``folder`` per input: ``<stem><suffix>`` (``x.csv`` → ``x.fit.json``).

    Inputs of one folder that share a stem get their suffix after it (``x.csv``, ``x.dat`` →
    ``x-csv.fit.json``, ``x-dat.fit.json``); inputs of other folders that share a name get their
    parent folders' names in front, as many as it takes (``a/x.csv``, ``b/x.csv`` →
    ``a-x.fit.json``, ``b-x.fit.json``; compared ignoring case), then a number. The names depend
    only on the inputs, in order, so two suffixes (``.fit.json``, ``.fit.png``) pair up. Keys are
    the inputs as given; the same input twice has one target.
    """
    paths = list(dict.fromkeys(Path(p) for p in inputs))
    folder = Path(folder)
    return {p: folder / (n + suffix) for p, n in zip(paths, _names(paths))}


def check_rerun_target(target, data=None) -> None:
    """Refuse, with an :class:`OutputError`, an existing ``target`` in an output folder that a run
    would replace but did not write: a file that is not a fit result of ctfit, or the result of
    another input than ``data`` (another folder's inputs fitted into the same folder). A rerun
    replaces its own earlier results. ``data`` None: ``target`` is the folder's ``summary.json``,
    replaced only when it is one ctfit wrote."""
    target = Path(target)
    if not os.path.lexists(target):
        return
    doc = read_json_or_none(target)
    if data is None:
        if isinstance(doc, dict) and isinstance(doc.get("results"), list) and "files" in doc:
            return
        why = "is not a summary of ctfit"
    else:
        earlier = doc.get("data") if isinstance(doc, dict) and isinstance(doc.get("fit"), dict) else None
        if isinstance(earlier, str) and _same_input(doc, data):
            return
        why = f"holds the fit of another input, {quote(earlier, 4096)}" if isinstance(earlier, str) else "is not a fit result of ctfit"  # (a path: whole)
    raise OutputError(f"{target}: the file exists and {why}; a run replaces only its own results: move it, or write the results "
                      "to another folder")


def write_own_result(target, chunks, data) -> None:
    """Write the fit result of ``data`` (``chunks``, :func:`~ctfit._io.files.atomic_write`) to
    ``target`` in a results folder, over nothing or over an earlier fit of the same input only,
    checked at the write (:func:`check_rerun_target`), not only before the run: a file that
    another run put there meanwhile (its input's fit of that name) is kept, and an
    :class:`OutputError` says so."""
    atomic_write(target, chunks, existing=lambda path: check_rerun_target(path, data))  # written once, checked where a file is


def _same_input(doc: dict, data) -> bool:
    """Whether a fit result ``doc`` is of the input ``data``: its ``data`` (the input as its run
    named it) is the same file, or a relative name that ``data``'s absolute path ends with (the
    earlier run was started in another folder: ``fits/a.fit.json`` of ``data/a.csv``, rerun on
    ``/home/me/data``) *and* its ``input_sha256`` is ``data``'s content's. A name alone may be
    another folder's file: ``a.csv`` of a run started in ``db1`` is not ``db2/a.csv``."""
    earlier = doc["data"]
    if same_file(earlier, data) or os.path.normpath(earlier) in {os.path.normpath(data), os.path.normpath(valid_name(os.fspath(data)))}:
        return True  # (valid_name: the name of a file that is not UTF-8, as its result holds it)
    tail = os.path.normpath(earlier)
    if os.path.isabs(tail) or tail.startswith("..") or not os.path.abspath(data).endswith(os.sep + tail):
        return False
    try:
        return isinstance(doc.get("input_sha256"), str) and doc["input_sha256"] == input_sha256(data)
    except (OSError, ValueError):  # gone, or not a file to read
        return False


def check_distinct(outputs) -> None:
    """Refuse, with an :class:`OutputError`, two of a run's outputs that are one file (whatever the
    spelling: :func:`same_file`), before any work: the later write would replace the other's
    result (a stored chain, a fit). ``outputs``: (option, path or None) pairs; a device such as
    ``/dev/null`` may be named by several."""
    seen: list[tuple[str, Path]] = []
    for option, path in outputs:
        if path is None or writes_in_place(path):
            continue
        for other, earlier in seen:
            if same_file(path, earlier):
                raise OutputError(f"{_at(option, path)}: is also {_at(other, earlier)}; each result needs a file of its own: give them different names")
        seen.append((option, Path(path)))


def is_fit_result(doc, data=None) -> bool:
    """Whether the JSON document ``doc`` is a fit result of ctfit (a ``fit`` section), and with
    ``data``, the fit of that input."""
    if not (isinstance(doc, dict) and isinstance(doc.get("fit"), dict)):
        return False
    return data is None or (isinstance(doc.get("data"), str) and _same_input(doc, data))


def is_posterior(doc) -> bool:
    """Whether the JSON document ``doc`` is a posterior ctfit wrote (an ``uncertainty`` section)."""
    return isinstance(doc, dict) and isinstance(doc.get("uncertainty"), dict)


def check_own_name(path, own, what: str, instead: str) -> Path:
    """Check, before writing, a file name that ``ctfit`` chooses itself beside a user's file
    (``X.not-converged.json``, ``X.posterior.json``): refused (:class:`OutputError`) where it is a
    symbolic link (a write would go through it, into a file the user never named) or an existing
    file that ``own(document)`` does not recognise as ``what`` (a file of the user's); the
    message ends with ``instead``, what the user can do. Returns ``path``."""
    path = Path(path)
    if path.is_symlink():
        raise OutputError(f"{path}: is a symbolic link (to {os.readlink(path)}); ctfit chooses this name itself and does not write through a link "
                          f"there: remove the link, or {instead}")
    if path.exists() and not writes_in_place(path) and not own(read_json_or_none(path)):
        raise OutputError(f"{path}: the file exists and is not {what}; ctfit chooses this name itself and replaces only a file of its own "
                          f"there: move the file, or {instead}")
    return path


PLOT_SOFTWARE = "ctfit"
"""How a PNG that ``ctfit`` wrote begins its ``Software`` text (``ctfit 0.1.0 (matplotlib 3.10.0)``):
what a rerun into a folder recognises as its own plot (:func:`check_rerun_plot`)."""


def plot_metadata(fmt: str) -> dict | None:
    """matplotlib's ``savefig(metadata=...)`` for a plot ``ctfit`` writes in the format ``fmt``: a
    PNG's ``Software`` text names ctfit (:data:`PLOT_SOFTWARE`, what :func:`check_rerun_plot`
    recognises); None (matplotlib's own) for other formats."""
    return {"Software": _software()} if fmt.lower() == "png" else None


@functools.cache
def _software() -> str:
    import matplotlib

    import ctfit  # its __version__: the package's own lookup, made once

    return f"{PLOT_SOFTWARE} {ctfit.__version__} (matplotlib {matplotlib.__version__})"


def png_software(path) -> str | None:
    """The ``Software`` text of the PNG at ``path`` (a ``tEXt`` chunk before the image data), or
    None: not a PNG, or none there. Reads the chunks' heads only, at most 64 KiB."""
    try:
        with open(path, "rb") as f:
            head = f.read(1 << 16)
    except OSError:
        return None
    if not head.startswith(b"\x89PNG\r\n\x1a\n"):
        return None
    at = 8
    while at + 8 <= len(head):
        size, kind = int.from_bytes(head[at: at + 4], "big"), head[at + 4: at + 8]
        if kind in (b"IDAT", b"IEND"):
            return None
        body = head[at + 8: at + 8 + size]
        if kind == b"tEXt" and body.startswith(b"Software\x00"):
            return body[len(b"Software\x00"):].decode("latin-1")
        at += 12 + size
    return None


def check_rerun_plot(target) -> None:
    """Refuse, with an :class:`OutputError`, an existing ``target`` in a plot folder that a run
    would replace but did not write: a file that is not a PNG of ``ctfit`` (its ``Software``
    text, :data:`PLOT_SOFTWARE`). A rerun replaces its own plots."""
    target = Path(target)
    if not os.path.lexists(target) or writes_in_place(target):
        return
    if not (png_software(target) or "").startswith(PLOT_SOFTWARE + " "):
        raise OutputError(f"{target}: the file exists and is not a plot of ctfit; a run replaces only its own plots: move it, or write the plots "
                          "to another folder")


def _holds_converged_fit(path: Path) -> bool:
    doc = read_json_or_none(path)  # nesting, huge numbers, a FIFO: not a converged fit
    return isinstance(doc, dict) and isinstance(doc.get("fit"), dict) and doc["fit"].get("converged") is True


def _fitting_name(stem: str, suffix: str, folder: Path) -> str:
    """``stem + suffix``, or, where that is longer than the folder's file names may be (255
    bytes on most file systems), ``stem`` cut short with a digest of the whole of it in front of
    ``suffix``: another stem never gets the same name."""
    limit = _name_max(folder)
    name = stem + suffix
    if len(os.fsencode(name)) <= limit:
        return name
    digest = "-" + hashlib.sha256(os.fsencode(stem)).hexdigest()[:12]
    room = limit - len(os.fsencode(digest + suffix))
    cut = os.fsencode(stem)[:room].decode("utf-8", errors="ignore")  # whole characters only
    return cut + digest + suffix


def unconverged_name(target) -> Path:
    """``<name>.not-converged.json`` beside ``target``: where a fit that did not converge goes
    when ``target`` holds a converged one (:func:`unconverged_target`)."""
    target = Path(target)
    stem = target.name[: -len(".json")] if target.name.endswith(".json") else target.name
    return target.with_name(_fitting_name(stem, ".not-converged.json", target.parent))


def unconverged_target(target) -> tuple[Path, str | None]:
    """Where a fit that did not converge is written, and what to tell the user.

    If ``target`` holds a converged fit (its JSON ``fit.converged`` is true), it is kept and the
    new result goes beside it, ``<name>.not-converged.json``; otherwise the result goes to
    ``target``, and the message says when that replaces a file. ``None``: nothing to say.
    The name beside is refused where it is a link or a file that is not a fit result of ctfit
    (:func:`check_own_name`; the command checks it before any work, too).
    """
    target = Path(target)
    if _holds_converged_fit(target):
        beside = check_own_name(unconverged_name(target), is_fit_result, "a fit result of ctfit", f"give -o another name than {target}")
        return beside, f"{target} holds a converged fit and is kept; the fit that did not converge is written to {beside}"
    if target.exists() and not writes_in_place(target):
        return target, f"{target} replaced by a fit that did not converge"
    return target, None
