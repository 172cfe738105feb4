"""The ``ctfit`` command.

The names the rest of the package uses, loaded on first use (``lazy_loader``).
"""

import lazy_loader

__getattr__, __dir__, __all__ = lazy_loader.attach(
    __name__,
    submod_attrs={
        "commands": ['SAMPLE_NOT_USABLE', 'app', 'main'],
        "leave": ['console'],
    },
)
