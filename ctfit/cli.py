"""The ``ctfit`` command (console script ``ctfit.cli:console``, which runs ``main``); its commands live in ``ctfit/_cli/``."""

from ._cli import SAMPLE_NOT_USABLE, app, console, main

__all__ = ["SAMPLE_NOT_USABLE", "app", "console", "main"]

if __name__ == "__main__":
    main()
