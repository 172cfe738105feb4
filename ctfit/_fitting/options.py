"""The keyword options every fit of one geometry shares, defined once: :func:`~ctfit.fit`'s.

``start``, ``fixed``, ``loss``, ``solver``, ``dtype``, ``starts`` and ``max_steps`` mean the same
in :func:`~ctfit.fit_batch` and :func:`~ctfit.fit_texels`; :func:`takes_fit_options` gives those
functions ``fit``'s keyword options, defaults included, in their signatures (``help()``, IDEs)
and hands them over as one ``options`` dict, so a default cannot differ between them.
"""

from __future__ import annotations

import functools
import inspect
from collections.abc import Callable

from .validate import check_solve_options

__all__ = ["takes_fit_options"]


def takes_fit_options(fit: Callable) -> Callable:
    """Decorator: ``fn(..., **options)`` accepts ``fit``'s keyword-only parameters, and gets all of
    them in ``options`` (defaults filled in, ``starts`` and ``max_steps`` checked as ``fit`` checks
    them); any other keyword is a ``TypeError``, as for ``fit``."""
    shared = [p for p in inspect.signature(fit).parameters.values() if p.kind is p.KEYWORD_ONLY]

    def decorate(fn: Callable) -> Callable:
        own = [p for p in inspect.signature(fn).parameters.values() if p.kind is not p.VAR_KEYWORD]
        signature = inspect.signature(fn).replace(parameters=own + shared)

        @functools.wraps(fn)
        def wrapper(*args, **kwargs):
            bound = signature.bind(*args, **kwargs)
            bound.apply_defaults()
            arguments = dict(bound.arguments)
            options = {p.name: arguments.pop(p.name) for p in shared}
            check_solve_options(options["starts"], options["max_steps"])  # as fit checks them
            return fn(**arguments, **options)

        wrapper.__signature__ = signature  # type: ignore[attr-defined]  # what inspect.signature reads
        return wrapper

    return decorate
