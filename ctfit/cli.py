"""The ``ctfit`` command (entry point ``ctfit.cli:main``); its commands live in ``ctfit/_cli/``."""

from ._cli import SAMPLE_NOT_USABLE, app, main

__all__ = ["SAMPLE_NOT_USABLE", "app", "main"]

if __name__ == "__main__":
    main()
