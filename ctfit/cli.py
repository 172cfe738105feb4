"""The ``ctfit`` command (entry point ``ctfit.cli:main``); its commands live in ``ctfit/_cli/``."""

from ._cli.app import SAMPLE_NOT_USABLE, UNUSABLE, UserError, app, main

__all__ = ["SAMPLE_NOT_USABLE", "UNUSABLE", "UserError", "app", "main"]

if __name__ == "__main__":
    main()
