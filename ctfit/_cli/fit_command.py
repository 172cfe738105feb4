"""The body of ``ctfit fit``: options and outputs checked first, then each file fitted (or files
fitted together by ``fit_batch``), reported, written; the exit status from the outcomes."""

from __future__ import annotations

import contextlib
import json
import math
import os
import re
from pathlib import Path
from types import SimpleNamespace
from typing import Any

from .inputs import check_param_out, load_material_file, material_inputs, read_data, refuse_dash, setup_jax
from .messages import UserError, cli_message, failure_line

__all__ = [
    "KEPT",
    "SUMMARY",
    "UNUSABLE",
    "check_fit_choices",
    "echo_wrote",
    "fit_command",
    "fit_exit_status",
    "fit_kwargs",
    "structure_choice",
    "report_file",
    "structure_from_options",
    "texel_structure",
    "write_summary",
]


DIFFUSE_CHOICES = ("auto", "none", "F0/pi", "spectrum", "constant", "transmitted")
FAMILY_CHOICES = ("auto", "metal", "plastic")


FRESNEL_FORMS = {"effective-n": "f0", "conductor": "conductor"}
"""``--fresnel``'s values → the library's ``Structure.fresnel``; not given: a structure the options
name takes the effective index, a data-chosen one tries both for a metal."""


def structure_from_options(base, o):
    """The one structure the options (or --material) name, or None when the data is to choose
    (--family, --diffuse or --lobes auto; :func:`~ctfit.choose_structure`)."""
    from .._model import Structure

    fres = FRESNEL_FORMS.get(o.fresnel)
    if base is not None:
        kw = {}
        if o.geometry:
            kw["geometry"] = o.geometry
        if fres:
            kw["fresnel"] = fres
        return Structure(**{**base.__dict__, **kw})
    family, diffuse = _family(o), _diffuse(o)
    if "auto" in (family, diffuse, o.lobes):
        return None
    fresnel = "n" if family == "plastic" else (fres or "f0")
    return Structure(lobes=int(o.lobes), geometry=o.geometry or "v-cavity", fresnel=fresnel, diffuse=None if diffuse == "none" else diffuse, family=family)


def texel_structure(o):
    """The one structure every texel of a texel store is fitted with: the options', each part left
    to the data (auto) taken from the paper's homogeneous material — a metal, R_d = F0/π, one lobe
    (a map of texels is not a file whose data can choose; docs/formats.md)."""
    from types import SimpleNamespace

    fixed = SimpleNamespace(**{**vars(o), "family": "metal" if _family(o) == "auto" else o.family,
                               "diffuse": "F0/pi" if _diffuse(o) == "auto" else _diffuse(o), "no_diffuse": False,
                               "lobes": "1" if o.lobes == "auto" else o.lobes})
    return structure_from_options(None, fixed)


def check_material_options(base, o) -> None:
    """--material sets the structure: --lobes, --family and --diffuse (--no-diffuse) agree with it
    or are left out (they were dropped without a word, while --geometry and --fresnel apply)."""
    st = base.structure
    has = {"--lobes": str(st.lobes), "--family": st.family, "--diffuse": "none" if st.diffuse is None else st.diffuse}
    for option, given in (("--lobes", o.lobes), ("--family", o.family), ("--diffuse", _diffuse(o))):
        if given != "auto" and given != has[option]:
            raise UserError(f"--material {o.material}: the material sets the structure ({st.lobes} lobe{'s' if st.lobes != 1 else ''}, family "
                            f"{st.family}, diffuse {has['--diffuse']}), and {option} {given} differs: leave {option} out, or change the material")


def _family(o) -> str:
    """--family; with auto, what the other options imply: a metal for --fresnel conductor and for
    a diffuse part none or F0/pi, a plastic for a transmitted one."""
    if o.family != "auto":
        return o.family
    if o.fresnel == "conductor" or _diffuse(o) in ("none", "F0/pi"):
        return "metal"
    return "plastic" if _diffuse(o) == "transmitted" else "auto"


def _diffuse(o) -> str:
    return "none" if o.no_diffuse else o.diffuse


def fit_command(o) -> int:
    """The ``fit`` command: options and outputs checked first, then every file; the exit status.
    One large CSV is parsed in a helper process meanwhile (:mod:`~ctfit._io.read_ahead`), started
    before anything imports JAX."""
    from .._io import start_read_ahead  # NumPy alone: JAX is not imported yet

    one = len(o.data) == 1 and o.workers is None and o.scheduler is None
    ahead = start_read_ahead(o.data[0]) if one else None
    try:
        with contextlib.ExitStack() as chains:
            o.chains = chains  # the --backend file's lock (_fit_plan), held until the command ends
            return _fit_command(o, ahead)
    finally:
        if ahead is not None:
            ahead.cancel()  # not taken (an option refused, say): stopped


def _fit_command(o, ahead) -> int:
    from .._runtime import prepare_runtime, programs_asked, progress_enabled, record_programs, start_preload
    from .fit_cluster import TEXEL_SUFFIXES, fit_on_cluster, fit_texel_command

    _check_fit_options(o)
    if len(o.data) == 1 and o.data[0].suffix.lower() in TEXEL_SUFFIXES:
        return fit_texel_command(_paths(o))
    o.folders = {k: _names_folder(getattr(o, k)) for k in ("output", "plot", "backend")}
    files = _expand(_paths(o).data)
    if len(files) > 1 or any(p.is_dir() for p in o.data):
        o.folders = dict.fromkeys(o.folders, True)  # several files, or a folder of them: results in folders
    plan = _fit_plan(files, o)
    o.json_lines = len(files) > 1  # --json of several files: one document a line (JSON Lines), a stream a parser reads
    setup_jax(o.float32)
    prepare_runtime()  # LAPACK's kernels registered while the fit reads its files
    check_fit_choices(o)
    base = load_material_file(o.material) if o.material else None
    if base is not None:
        check_material_options(base, o)
    if o.workers is not None or o.scheduler is not None:
        outcomes, hashes = fit_on_cluster(files, o, base, plan, progress_enabled(o.quiet))
    else:
        signature, asked = program_signature(o, base), programs_asked()
        preload = start_preload(signature)  # last run's programs, loaded while the files are read
        ended = False
        try:
            hashes = {}
            summary = o.output is not None and o.folders["output"]  # the hashes serve the summary alone
            outcomes = _fit_each(files, o, base, plan, progress_enabled(o.quiet), ahead, hashes if summary else None)
            ended = True
        finally:
            preload.finish()
            record_programs(signature, asked, write=ended)  # a run stopped midway leaves the record as it was
    if o.output is not None and o.folders["output"]:
        write_summary(o.output / SUMMARY, files, outcomes, plan, hashes)
    return fit_exit_status(outcomes)


PROGRAM_OPTIONS = ("family", "lobes", "geometry", "fresnel", "diffuse", "no_diffuse", "loss", "solver", "starts", "max_steps", "param_out",
                   "float32", "sample_", "walkers")
"""The options of ``ctfit fit`` that shape the programs it compiles (with the data's bands and layout)."""


def program_signature(o, base) -> str:
    """What names a ``ctfit fit`` run's programs before its data is read (:mod:`~ctfit._runtime.program_preload`):
    the options that shape them and the structure of ``--material``."""
    fields = {k: getattr(o, k, None) for k in PROGRAM_OPTIONS}
    fields["material"] = repr(base.structure) if base is not None else None
    return "fit " + json.dumps(fields, sort_keys=True, default=str)


SUMMARY = "summary.json"
"""The name of the summary that a run writing its results into a folder (``-o OUTDIR``) puts there."""

KEPT = " (kept: fitted earlier from the same input)"


def _names_folder(value) -> bool:
    """Whether an output option names a folder: it ends with a slash or is an existing folder."""
    import os

    return value is not None and (str(value).endswith(("/", os.sep)) or os.path.isdir(value))


def _paths(o):
    """``o`` with its output options (given as text, to see a trailing slash) as paths."""
    for k in ("output", "plot", "backend"):
        if isinstance(getattr(o, k), str):
            setattr(o, k, Path(getattr(o, k)))
    return o


def write_summary(target: Path, files: list[Path], outcomes: list[tuple[str, str]], plan: dict, hashes: dict) -> None:
    """``summary.json``: per file its outcome, result file, input hash and (failed) the reason."""
    from .._io import atomic_write, input_sha256

    def sha(path):
        try:
            return hashes[path] if path in hashes else input_sha256(path)
        except (OSError, ValueError):  # unreadable now, or not a file to read (a FIFO, /dev/zero): no hash
            return None

    rows = []
    for path, (outcome, what) in zip(files, outcomes):
        rows.append(dict(data=str(path), outcome=outcome, kept=what.endswith(KEPT),
                         result=None if outcome == "failed" else str(getattr(plan[path], "written", plan[path].json)), input_sha256=sha(path),
                         reason=what if outcome == "failed" else None))
    count = {k: sum(r["outcome"] == k for r in rows) for k in ("converged", "not converged", "failed")}
    atomic_write(target, [json.dumps(dict(files=len(rows), **count, results=rows), indent=2) + "\n"])
    echo_wrote(target)


def _check_fit_options(o) -> None:
    """Refuse bad option values before any work (typer's ``min=`` checks the counts)."""
    for value, option in ((o.output, "-o"), (o.plot, "--plot"), (o.backend, "--backend")):
        refuse_dash(value, option)
    if o.geometry not in (None, "v-cavity", "smith", "smith-rational"):
        raise UserError(f"--geometry must be v-cavity, smith or smith-rational, got {o.geometry!r}")
    if o.fresnel is not None and o.fresnel not in FRESNEL_FORMS:
        raise UserError(f"--fresnel must be {' or '.join(FRESNEL_FORMS)}, got {o.fresnel!r}")
    from .._model import MAX_LOBES

    if o.lobes != "auto" and not (o.lobes.isdigit() and 1 <= int(o.lobes) <= MAX_LOBES):
        raise UserError(f"--lobes must be 1..{MAX_LOBES} or 'auto', got {o.lobes!r}")
    if o.family not in FAMILY_CHOICES:
        raise UserError(f"--family must be one of {', '.join(FAMILY_CHOICES)}, got {o.family!r}")
    if o.diffuse not in DIFFUSE_CHOICES:
        raise UserError(f"--diffuse must be one of {', '.join(DIFFUSE_CHOICES)}, got {o.diffuse!r}")
    if o.no_diffuse and o.diffuse not in ("auto", "none"):
        raise UserError(f"--no-diffuse and --diffuse {o.diffuse} contradict each other")
    if _family(o) == "plastic" and (o.fresnel == "conductor" or _diffuse(o) == "F0/pi"):
        raise UserError("a plastic has one real index and its own diffuse part: leave out --fresnel conductor and --diffuse F0/pi")
    if _family(o) == "metal" and _diffuse(o) == "transmitted":
        raise UserError("--diffuse transmitted (through a dielectric interface) is for --family plastic")
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
    _check_extras(o)


def _check_extras(o) -> None:
    """The extras the options need, before any work (one line naming a missing one)."""
    from .._runtime import need

    if o.workers is not None or o.scheduler is not None:
        need("cluster", "--workers" if o.workers is not None else "--scheduler")
    if o.plot is not None:
        need("plots", "--plot")
    if o.sample_:
        need("posterior", "--sample")


def _check_cluster_options(o) -> None:
    """--workers / --scheduler: one structure for all files, results kept in -o; a local
    cluster of a size the machine can run."""
    from .._runtime import check_local_workers

    which = "--workers" if o.workers is not None else "--scheduler"
    if o.workers is not None and o.scheduler is not None:
        raise UserError("--workers makes a local cluster and --scheduler uses an existing one: give one of them")
    if o.output is None:
        raise UserError(f"{which} needs -o (the results are written per file as they complete, and a re-run skips the files done)")
    if o.sample_:
        raise UserError(f"{which} fits only; leave out --sample (or sample the files afterwards)")
    if o.as_json:
        raise UserError(f"{which} writes each result to -o; leave out --json")
    try:
        check_local_workers(o.workers)
    except ValueError as e:
        raise UserError(str(e).replace("workers = ", "--workers ", 1)) from None


def check_fit_choices(o) -> None:
    """Refuse an unknown --loss or --solver before the first file (the library's lists)."""
    from .._fitting import LOSSES, SOLVERS

    if o.loss not in ("auto", *LOSSES):
        raise UserError(f"--loss must be auto or one of {', '.join(LOSSES)}, got {o.loss!r}")
    if o.solver not in SOLVERS:
        raise UserError(f"--solver must be one of {', '.join(SOLVERS)}, got {o.solver!r}")


def _fit_plan(files: list[Path], o) -> dict[Path, SimpleNamespace]:
    """Every file's targets (json, plot, backend; None: not written) and name, checked before any work.

    An option that names a file (one input file): that path; one that names a folder (``o.folders``:
    several files, a folder of them, a trailing slash, an existing folder): distinct files in it
    (``result_targets``), none a symbolic link, and ``summary.json`` beside the results. A chain
    file that another run is writing is refused; one file's chain stays locked in ``o.chains``
    until the command ends (of several, each is locked while it is sampled: a descriptor each
    for the whole command could run out).
    """
    from .._io import (
        InputFiles,
        check_backend,
        check_distinct,
        check_output,
        check_output_folder,
        check_rerun_plot,
        check_rerun_target,
        result_targets,
        unconverged_name,
        unconverged_target,
    )
    from .sample_command import check_posterior_plots, result_stem

    many, inputs = len(files) > 1, InputFiles([*files, *material_inputs(o.material)])  # each input looked up once, not once per output

    def targets(key, value, option, suffix, check):
        if value is None:
            return dict.fromkeys(files)
        if not o.folders[key]:
            return {files[0]: check(Path(value), False)}
        found = result_targets(files, check_output_folder(value, option=option), suffix)
        return {p: check(target, True) for p, target in found.items()}

    def chain(target, chosen):  # one chain: locked from now on; several: checked now, each locked by its own sampling run
        return check_backend(target, inputs, resume=o.resume, overwrite=o.overwrite, chosen=chosen, hold=None if many else o.chains)

    json_ = targets("output", o.output, "-o", ".fit.json", lambda t, c: _json_name(check_output(t, inputs, option="-o", chosen=c)))
    plot = targets("plot", o.plot, "--plot", ".fit.png", lambda t, c: _plot_format(check_output(t, inputs, option="--plot", chosen=c)))
    backend = targets("backend", o.backend if o.sample_ else None, "--backend", ".h5", chain)
    if o.output is not None and o.folders["output"]:  # a folder: what is there and not this run's own is kept
        for p, target in json_.items():
            check_rerun_target(target, p)
        check_rerun_target(check_output(o.output / SUMMARY, inputs, option="-o", chosen=True))
    if o.plot is not None and o.folders["plot"]:
        for target in plot.values():
            check_rerun_plot(target)
    names = result_targets(files, Path(), "") if many else {files[0]: Path(files[0].stem)}
    own = o.output is not None and o.folders["output"]  # results in a folder: each written over nothing or its own earlier result only
    plan = {p: SimpleNamespace(json=json_[p], plot=plot[p], backend=backend[p], name=names[p].name, own=own) for p in files}
    for t in plan.values():
        check_distinct([("-o", t.json), ("--plot", t.plot), ("--backend", t.backend)])
        if t.json is not None and os.path.lexists(unconverged_name(t.json)):
            unconverged_target(t.json)  # where a fit that does not converge would go: refused now if that is not ctfit's to replace
        if o.sample_ and t.plot is not None:
            check_posterior_plots(t.plot.parent, result_stem(t.json) if t.json is not None else t.name)
    return plan


def _json_name(path: Path) -> Path:
    """``path`` for a fit-result JSON; refused when it is named ``.toml``, which ctfit reads as TOML:
    the result would not load (``ctfit color``, ``--material``) and a material file there is lost."""
    if path.suffix.lower() == ".toml":
        raise UserError(f"-o {path}: a fit result is written as JSON; name it .json (a .toml file is read as TOML)")
    return path


def _plot_format(path: Path) -> Path:
    """Refuse, before any work, a plot file whose suffix names no format matplotlib writes."""
    if not path.suffix:
        return path  # PNG
    from matplotlib.backend_bases import FigureCanvasBase

    formats = FigureCanvasBase.get_supported_filetypes()
    if path.suffix[1:].lower() not in formats:
        raise UserError(f"--plot {path}: matplotlib writes no {path.suffix} files; give a name ending in {', '.join('.' + f for f in sorted(formats))}")
    return path


def _fit_each(files: list[Path], o, base, plan: dict, show: bool, ahead=None, hashes: dict | None = None) -> list[tuple[str, str]]:
    """Fit every file; several: a failure is one error line and the rest go on. [(outcome, what)].
    ``hashes``: filled with each file's SHA-256 as it is read (for the summary: the content that
    was fitted, hashed off the report's path instead of read again at the end).

    Several files fitted with one structure (not ``--lobes auto``, not ``--sample``) are fitted
    together by ``fit_batch``, a window of files at a time (:func:`_read_window`), and then
    reported file by file, as they would be one at a time; the next windows are fitted and read
    in background threads while one is reported (:func:`_windows`), and each result file is
    written in a writer thread while the next files are reported (:data:`RESULT_WRITERS`): its
    ``wrote`` line, or its error, follows once it is written."""
    import collections
    import concurrent.futures

    from .._runtime import bar

    together = len(files) > 1 and not o.sample_ and structure_from_options(base.structure if base else None, o) is not None
    outcomes: list[tuple[str, str]] = []
    windows = _windows(files, o, base, hashes) if together else None
    writer = concurrent.futures.ThreadPoolExecutor(RESULT_WRITERS, thread_name_prefix="ctfit-write") if together else None
    queued: collections.deque = collections.deque()  # (path, outcome or a failure, the write under way or None), in the files' order
    fitted: dict[Path, Any] = {}  # path → (measurement, FitResult), or an exception (_windows)
    try:
        for path in bar(files, desc="files", enabled=show and len(files) > 1):
            try:
                if not together:
                    queued.append((path, _fit_file(path, o, base, plan[path], show, ahead, hashes), None))
                else:
                    if path not in fitted:
                        assert windows is not None  # together
                        fitted = next(windows)
                    got = fitted.pop(path)
                    if isinstance(got, Exception):
                        raise got
                    meas, res = got
                    outcome = report_file(path, meas, res, o, plan[path], show, sha=None if hashes is None else hashes.get(path), writer=writer)
                    queued.append((path, outcome, plan[path].writing))
            except (UserError, ValueError, OSError, KeyError) as e:
                if len(files) == 1:
                    raise
                queued.append((path, e, None))
            _settle(queued, outcomes, wait=False)
        _settle(queued, outcomes, wait=True)
    finally:
        # Stopped by anything else (Ctrl-C, an error of ctfit's own): the windows' threads end
        # here, in this thread. Left to the garbage collector, the generator's close (which
        # joins them) ran wherever a collection happened, once inside Python's own lock of
        # thread starts: a later command in the process hung for good. Writes under way end first.
        if windows is not None:
            windows.close()
        if writer is not None:
            writer.shutdown(wait=True)
    return outcomes


RESULT_WRITERS = 4
"""Result files written at once, each in its own thread, while the next files are reported. A
write waits for the disk (:func:`~ctfit._io.atomic_write` syncs the new file before its rename),
and writes in several threads share the file system's journal commits. On this machine's disk,
busy, a sync took 0.7–3.6 ms (256 files 0.2–0.9 s one after another, 0.1–0.17 s in 4 threads);
quiet, the 256 files' run took 1.02× the time it takes without any sync (6 pairs): the threads
matter where syncs are slow (a busy or network disk)."""


def _settle(queued, outcomes: list[tuple[str, str]], *, wait: bool) -> None:
    """Move the files of ``queued`` whose result is written (all of them, with ``wait``) to
    ``outcomes``, in the files' order: a ``wrote`` line for each result written, an error line for
    each file that failed (its report, or its write)."""
    from .._runtime import echo

    while queued and (wait or queued[0][2] is None or queued[0][2].done()):
        path, outcome, writing = queued.popleft()
        try:
            if isinstance(outcome, Exception):
                raise outcome
            if writing is not None:
                echo_wrote(*writing.result())
        except (UserError, ValueError, OSError, KeyError) as e:
            line = failure_line(path, e)
            echo(f"error: {line}", err=True)
            outcomes.append(("failed", line))
            continue
        outcomes.append((outcome, str(path)))


WINDOW_FILES = 64
"""The most files read and fitted at once (:func:`_read_window`)."""

FITTING_WINDOWS = 2
"""Windows fitted at once, each in its own thread: one window's serial parts (laying out its
files, making each file's report) run while the other's solve (256 files of 2,000 samples, with
the programs loaded ahead: 0.88× the time of one window at a time, paired)."""


def _windows(files: list[Path], o, base, hashes: dict | None = None):
    """The fits of ``files`` a window at a time (path → (measurement, FitResult) or the exception
    that stopped it), in three stages that overlap: while the caller reports one window's fits,
    the next windows are fitted (:func:`_fit_window`, :data:`FITTING_WINDOWS` at once, in threads)
    and the one after them read (:func:`_read_window`, in another thread). A window's fit is
    started by the thread that read it, as soon as it is read (its fit waits there for a fitting
    thread, not for the caller to ask for the window before); a window is read once the caller has
    taken the one two before it, so three windows are held at most, the one being reported among them.
    ``hashes``: each file read gets its SHA-256 there, by the reading thread (:func:`_hash_into`)."""
    import collections
    import concurrent.futures

    reader = concurrent.futures.ThreadPoolExecutor(1, thread_name_prefix="ctfit-read")
    fitter = concurrent.futures.ThreadPoolExecutor(FITTING_WINDOWS, thread_name_prefix="ctfit-fit")

    def read_and_fit(chunk: list[Path]) -> tuple[int, concurrent.futures.Future]:
        ready, failed, fixed = _read_window(chunk, o, base)
        fit = fitter.submit(_fit_window, ready, failed, fixed, o, base)
        _hash_into(hashes, [path for path, _, _ in ready])
        return len(ready) + len(failed), fit

    try:
        reading: concurrent.futures.Future | None = reader.submit(read_and_fit, files)
        fits: collections.deque = collections.deque()  # the windows read, their fits started, in order
        while reading is not None:
            taken, fit = reading.result()
            files = files[taken:]
            fits.append(fit)
            reading = reader.submit(read_and_fit, files) if files else None
            if len(fits) >= FITTING_WINDOWS:
                yield fits.popleft().result()
        while fits:
            yield fits.popleft().result()
    finally:  # closed early (the caller stopped): what has not started is dropped, what runs ends first
        for pool in (reader, fitter):
            pool.shutdown(wait=True, cancel_futures=True)


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


def _hash_into(hashes: dict | None, paths: list[Path]) -> None:
    """``hashes[path]``: the SHA-256 of each file just read (``hashes`` None: nothing); one that
    cannot be read now is left out (the summary tries it again)."""
    from .._fitting import input_sha256

    if hashes is None:
        return
    for path in paths:
        try:
            hashes[path] = input_sha256(path)
        except (OSError, ValueError):
            pass


def _fit_file(path: Path, o, base, t: SimpleNamespace, show: bool, ahead=None, hashes: dict | None = None) -> str:
    """Read (``ahead``: parsed by a helper process, :mod:`~ctfit._io.read_ahead`), fit, print and
    write one file's results; its outcome (:func:`report_file`). ``hashes``: :func:`_hash_into`."""
    meas = read_data(path, o.param_out, ahead)
    _hash_into(hashes, [path])
    return report_file(path, meas, _fit_measurement(meas, o, base, show), o, t, show, sha=None if hashes is None else hashes.get(path))


def _read_window(files: list[Path], o, base) -> tuple[list, dict, tuple]:
    """The first of ``files`` read — one at least, more while they hold fewer than
    ``SAMPLE_BUDGET`` samples in all and number fewer than :data:`WINDOW_FILES`, so memory stays
    bounded: ([(path, measurement, start)], {path: the exception that reading it or its start
    raised}, the fixed parameters)."""
    from .._fitting import SAMPLE_BUDGET, start_from_material

    st = structure_from_options(base.structure if base else None, o)
    failed: dict = {}
    ready: list[tuple[Path, Any, Any]] = []
    fixed, held = (), 0
    for path in files:
        if held >= SAMPLE_BUDGET or len(failed) + len(ready) >= WINDOW_FILES:
            break
        try:
            meas = read_data(path, o.param_out)
            start, fixed = start_from_material(base, st, meas) if base else (None, ())
            ready.append((path, meas, start))
            held += len(meas)
        except (UserError, ValueError, OSError, KeyError) as e:
            failed[path] = e
    return ready, failed, fixed


def _fit_window(ready: list, failed: dict, fixed: tuple, o, base) -> dict:
    """A window of :func:`_read_window` fitted by ``fit_batch``: path → (measurement, FitResult),
    or the exception that stopped that file (reading it, its start, or its fit)."""
    from .._fitting import fit_batch

    st = structure_from_options(base.structure if base else None, o)
    fits = fit_batch([m for _, m, _ in ready], st, start=[s for _, _, s in ready], fixed=fixed, return_errors=True, **fit_kwargs(o))
    done = dict(failed)
    for (path, meas, _), res in zip(ready, fits):
        done[path] = res if isinstance(res, Exception) else (meas, res)
    return done


def report_file(path: Path, meas, res, o, t: SimpleNamespace, show: bool, sha: str | None = None, writer=None) -> str:
    """Print and write one file's results; its outcome: "converged", "not converged", or with
    --sample ``UNUSABLE`` when the fit converged but its posterior is not usable. ``sha``: the
    input's SHA-256 as it was read, written into the result (a rerun from another folder knows
    its own results by it). ``writer`` (an executor; not with --sample): the result file is
    written there, and ``t.writing`` is the future of that write, giving the arguments of
    :func:`echo_wrote` once written; the caller says so (without: said here, ``t.writing`` None)."""
    res.material.meta["data"] = str(path)
    if sha is not None:
        res.material.meta["input_sha256"] = sha
    target, note = t.json, None
    if target is not None and not res.converged:
        from .._io import unconverged_target

        target, note = unconverged_target(target)
    t.written = target  # the summary names the file written (a fit that did not converge may go beside a converged one)
    usable, t.writing = True, None
    if o.sample_:
        usable = _sample_and_report(res, meas, path, o, t, target)
    elif writer is not None:
        t.writing = _report_fit(res, path, o, target, own=t.own, writer=writer, wrote=(target, note))
    else:
        _report_fit(res, path, o, target, own=t.own)
    if t.writing is None:
        echo_wrote(target, note)
    if t.plot is not None:
        from .._fitting import plot_fit

        plot_fit(res, meas, t.plot)
        echo_wrote(t.plot)
    return "not converged" if not res.converged else ("converged" if usable else UNUSABLE)


def _fit_measurement(meas, o, base, show: bool):
    """One fit: the structure of the options (or --material), or the one the data chooses."""
    from .._fitting import choose_structure, fit as run_fit, start_from_material
    from .._runtime import bar, echo

    kw = fit_kwargs(o)
    st = structure_from_options(base.structure if base else None, o)
    if st is None:
        res, tried = choose_structure(meas, progress=lambda it: bar(it, desc="structures", enabled=show), **structure_choice(o), **kw)
        if not o.as_json:
            echo(_choice_table(res))
        return res
    start, fixed = start_from_material(base, st, meas) if base else (None, ())
    return run_fit(meas, st, start=start, fixed=fixed, **kw)


def structure_choice(o) -> dict:
    """The candidates of :func:`~ctfit.choose_structure` that the options leave open (where
    :func:`structure_from_options` gives None): families, lobes, diffuse part, geometry, Fresnel."""
    family, diffuse = _family(o), _diffuse(o)
    return dict(families=("metal", "plastic") if family == "auto" else (family,), lobes=(1, 2, 3) if o.lobes == "auto" else (int(o.lobes),),
                diffuse=None if diffuse == "auto" else diffuse, geometry=o.geometry or "v-cavity",
                fresnel=FRESNEL_FORMS.get(o.fresnel))  # not given: both forms for a metal


def fit_kwargs(o) -> dict:
    """The options of ``fit`` (and ``fit_batch``) that the command line sets."""
    import jax.numpy as jnp

    return dict(loss=o.loss, solver=o.solver, dtype=jnp.float32 if o.float32 else jnp.float64, starts=o.starts, max_steps=o.max_steps)


def _report_fit(res, path: Path, o, target, own: bool = False, writer=None, wrote: tuple = ()):
    """The table (or JSON) on stdout; the fit-result JSON written to ``target``. The two JSON
    documents are one (:func:`~ctfit._fitting.fit_result_to_dict`), made and encoded once: the
    file's text is what ``--json`` prints where it holds only ASCII characters (``json.dumps``
    escapes the others on stdout). ``json.dumps`` with an indent runs Python's own encoder, so
    encoding twice cost a database a few milliseconds a file (256 files: 0.92× the time once).
    ``writer``: the file is written there; returns the write's future (its value: ``wrote``), or
    None where nothing is written."""
    from .._fitting import fit_result_to_dict, format_fit_table
    from .._io import atomic_write, material_json, write_own_result
    from .._runtime import echo

    if not o.as_json:
        echo(cli_message(format_fit_table(res, str(path))))
    if not o.as_json and target is None:
        return None
    doc = fit_result_to_dict(res)
    text = material_json(doc)
    if o.as_json:
        echo(json.dumps(json.loads(text), separators=(",", ":")) if getattr(o, "json_lines", False) else ascii_json(text[:-1]))
    if target is None:
        return None

    def write() -> tuple:
        if own:
            write_own_result(target, [text], path)
        else:
            atomic_write(target, [text])
        return wrote

    if writer is None:
        write()
        return None
    return writer.submit(write)


def ascii_json(text: str) -> str:
    """JSON text with every character past ASCII (DEL too) escaped as ``json.dumps`` escapes it
    (``\\u00e9``; a surrogate pair beyond the first plane): what ``--json`` prints, whatever
    the terminal's encoding. The characters are inside strings, so the document is the same."""
    if text.isascii() and "\x7f" not in text:
        return text
    return _NOT_ASCII.sub(lambda m: json.dumps(m[0]).strip('"'), text)


_NOT_ASCII = re.compile(r"[^\x00-\x7e]")


def _sample_and_report(res, meas, path: Path, o, t: SimpleNamespace, target) -> bool:
    """--sample: the posterior of the fit, its tables (or JSON) on stdout, written to ``target``;
    whether the posterior is usable."""
    import warnings

    from .._fitting import format_fit_table
    from .._runtime import echo, progress_mode
    from .._sampling import ChainTooShortWarning, format_uncertainty_table
    from .sample_command import fit_sample_body, run_longer

    with warnings.catch_warnings():
        warnings.simplefilter("ignore", ChainTooShortWarning)  # listed in the table and the JSON
        doc = fit_sample_body(
            res, meas, walkers=o.walkers, steps=o.steps, burn=o.burn, thin=o.thin, seed=o.seed, backend=t.backend,
            resume=o.resume, overwrite=o.overwrite, output=target, own_of=path if t.own else None, plot_dir=None if t.plot is None else t.plot.parent,
            plot_stem=t.name, progress=progress_mode(o.quiet),
        )
    if o.as_json:
        echo(json.dumps(doc, separators=(",", ":")) if getattr(o, "json_lines", False) else json.dumps(doc, indent=2))
    else:
        echo(cli_message(format_fit_table(res, str(path))))  # the library's argument names as options
        echo(cli_message(format_uncertainty_table(doc, str(path))))
    hint = run_longer(doc, backend=t.backend)
    if hint:
        echo(hint, err=True)
    return bool(doc["uncertainty"]["usable"])


def echo_wrote(target, note: str | None = None) -> None:
    """'wrote TARGET' on stderr, on its own line after what went to stdout (and a note before it)."""
    from .._runtime import echo

    if note:
        echo(f"warning: {note}", err=True)
    if target is not None:
        echo(f"wrote {target}", err=True)


def _expand(paths) -> list[Path]:
    """The measurement files named, folders expanded (sorted); each file once, however it is
    spelled (``s.csv``, ``/abs/s.csv``, a link to it: by its resolved path), as first named."""
    files: dict[Path, Path] = {}
    for p in paths:
        if p.is_dir():
            found = sorted(q for q in p.iterdir() if q.suffix.lower() in (".csv", ".binary", ".alta", ".dat", ".bsdf"))
            if not found:
                raise UserError(f"{p}: folder has no measurement files (.csv, .binary, .alta, .dat, .bsdf)")
            for q in found:
                files.setdefault(Path(os.path.realpath(q)), q)  # (no error for a link loop: it is reported when read)
        elif not p.exists():
            from .._io import broken_link

            raise UserError(f"{p}: {broken_link(p) or 'no such file'}")
        else:
            files.setdefault(Path(os.path.realpath(p)), p)
    return list(files.values())


def _percent(x: float | None) -> str:
    """A relative error in the choice table: "4.3%", "5.2e+05%" past 1,000 %, "–" where not known."""
    if x is None or not math.isfinite(x):
        return "–" if x is None else f"{x}"
    return f"{x * 100:.2g}%" if x >= 10 else f"{x:.1%}"


def _choice_table(res) -> str:
    """The structures the data chose among (``res.stats["structure_choice"]``): each one's
    parameters, median relative error, BIC; where they were compared on a screening sample, its
    size and each one's median relative error on the held-out pairs, which chose; and the 90th
    percentile (held-out where screened), which chose where one is far off and far worse."""
    screening = res.stats.get("structure_screening") or {}
    screened = screening.get("samples", 0) < screening.get("of", 0)
    held = screened and bool(screening.get("heldout_samples"))
    how = (f"lowest median |f−y|/y on {screening.get('heldout_samples', 0):,} held-out samples" if held else "lowest BIC") + ", unless its p90 is far worse"
    on = f"; fitted to {screening['samples']:,} of its {screening['of']:,} samples, the choice then fitted to all" if screened else ""
    lines = [f"structure chosen by the data ({how}{on}):",
             f"  {'structure':<42} {'params':>6} {'median |f−y|/y':>15}" + (f" {'held-out':>9}" if held else "") + f" {'p90':>9} {'BIC':>14} {'converged':>10}"]
    for row in res.stats["structure_choice"]:
        median, out = row.get("median_relative_error"), row.get("heldout_median_relative_error")
        tail = row.get("heldout_p90_relative_error") if held else row.get("p90_relative_error")
        ho = f" {_percent(out):>9}" if held else ""
        mark = "  <- chosen" if row["chosen"] else ""
        lines.append(f"  {row['structure']:<42} {row['params']:>6} {_percent(median):>15}{ho} {_percent(tail):>9} {row['bic']:>14.6g}"
                     f" {str(row['converged']):>10}{mark}")
    return "\n".join(lines)
