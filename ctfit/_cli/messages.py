"""What the ``ctfit`` command prints when something goes wrong: one line, in the CLI's words.

Input errors print one ``error:`` line and exit with status 2; warnings print as one line
``warning: MESSAGE``; a library message's Python argument names become the options that set them.
"""

from __future__ import annotations

import errno
import re

import typer

__all__ = ["UserError", "cli_message", "echo", "failure_line", "os_error_text", "run_body", "show_warning"]


class UserError(Exception):
    """An error caused by the input, reported without a traceback."""


_CLI_PHRASES = {  # library phrases → the command line's (longest first where one holds another)
    "pass resume=False": "leave out --resume",
    "resume=False": "leave out --resume",
    "overwrite=True": "--overwrite",
    "param_out=...": "--param-out",
    "(structure=: fewer lobes, no diffuse part)": "(--lobes, --no-diffuse)",
    "(structure=)": "(--lobes)",
    "(start=)": "(--material)",
    "(dtype=float64)": "(without --float32)",
    '(solver="lm", the default)': "(--solver lm, the default)",
    "(starts=3)": "(--starts 3)",
}


_CLI_NAMES = {  # library argument → the option that sets it, for library messages shown by the CLI
    "param_out": "--param-out",
    "max_steps": "--max-steps",
    "max_theta": "--max-theta",
    "n_pairs": "--samples",
    "noise": "--noise",
    "walkers": "--walkers",
    "steps": "--steps",
    "thin": "--thin",
    "burn": "--burn",
    "wavelength_step": "--step",
    "angle_deg": "--angle",
    "seed": "--seed",
    "loss": "--loss",
}


_CLI_NAME = re.compile(r"(?<![\w-])(" + "|".join(_CLI_NAMES) + r")(?==|\s+must\b)")
_CLI_BARE = re.compile(r"(?<![\w-])(" + "|".join(_CLI_NAMES) + r")=(?=[),;]|\s|$)")  # "more max_steps=," → "more --max-steps,"


def _nothing_to_turn(text: str) -> bool:
    """Whether ``text`` holds none of what the phrases and patterns above need: an ``=`` right
    after a word character, or ``must``. A fit's table (some 40 lines, its ``=`` all after a space)
    is looked through in 0.01 ms instead of a quarter of a millisecond."""
    return "must" not in text and "=" not in text.replace(" =", "")


def cli_message(text: str) -> str:
    """A library message with its Python argument names (``param_out=``) turned into options."""
    return text if _nothing_to_turn(text) else _turned(text)


def _turned(text: str) -> str:
    for phrase, option in _CLI_PHRASES.items():
        text = text.replace(phrase, option)
    text = _CLI_BARE.sub(lambda m: _CLI_NAMES[m[1]], text)
    return _CLI_NAME.sub(lambda m: _CLI_NAMES[m[1]], text)


def show_warning(message, category, filename, lineno, file=None, line=None):
    """``warnings.showwarning`` for the CLI: one ``warning: MESSAGE`` line, no source location."""
    from .._runtime import echo

    echo(f"warning: {cli_message(str(message))}", err=True)


def run_body(fn):
    """Run a command body: warnings as one line each, input errors (and a request for more memory than
    the machine has) as one line and exit status 2."""
    import warnings

    with warnings.catch_warnings():
        warnings.showwarning = show_warning
        try:
            return fn()
        except UserError as e:
            echo(f"error: {e}", err=True)
            raise typer.Exit(2) from None
        except ImportError as e:
            from .._runtime import MissingExtraError

            if not isinstance(e, MissingExtraError):
                raise
            echo(f"error: {e}", err=True)  # the feature, the packages, the pip command
            raise typer.Exit(2) from None
        except OSError as e:
            echo(f"error: {os_error_text(e)}", err=True)
            raise typer.Exit(2) from None
        except (ValueError, KeyError) as e:
            echo(f"error: {cli_message(str(e))}", err=True)
            raise typer.Exit(2) from None
        except MemoryError as e:  # an allocation the machine cannot hold (``simulate --samples 10**15``): one line, not a traceback
            echo(f"error: not enough memory{f' ({e})' if str(e) else ''}: ask for less (fewer samples or files at once)", err=True)
            raise typer.Exit(2) from None


def echo(text: str, *, err: bool = False) -> None:
    """One line on stdout (stderr with ``err``), as ``ctfit._runtime.echo``: a closed pipe is not an error."""
    from .._runtime import echo as write

    write(text, err=err)


_PLAIN = {errno.ENOENT: "no such file", errno.EISDIR: "is a folder, not a file", errno.ENOTDIR: "a part of the path is a file, not a folder",
          errno.EACCES: "permission denied", errno.EPERM: "not permitted", errno.ENAMETOOLONG: "the name is too long",
          errno.ENOSPC: "no space left on the device", errno.EROFS: "the file system is read-only"}


def os_error_text(e: OSError) -> str:
    """``PATH: reason`` in plain words for an error of the system (``[Errno 2] …`` → ``x.csv: no such file``)."""
    if e.errno is None or e.strerror is None:
        return cli_message(str(e))
    import os

    own = e.strerror != os.strerror(e.errno)  # ctfit's own words (``the file is read-only …``)
    reason = e.strerror if own else _PLAIN.get(e.errno, e.strerror[:1].lower() + e.strerror[1:])
    return f"{e.filename}: {reason}" if e.filename is not None else reason


def failure_line(path, err: Exception) -> str:
    """``PATH: reason`` for a file that failed among several (the reason in the CLI's words)."""
    message = os_error_text(err) if isinstance(err, OSError) else cli_message(str(err))
    return message if message.startswith(f"{path}:") else f"{path}: {message}"
