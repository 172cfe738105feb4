"""The posterior of a fit: emcee sampling, priors, checks, summaries, plots.

The names the rest of the package uses, loaded on first use (``lazy_loader``).
"""

import lazy_loader

__getattr__, __dir__, __all__ = lazy_loader.attach(
    __name__,
    submod_attrs={
        "emcee_run": ['ChainTooShortWarning', 'SampleResult', 'sample'],
        "outputs": ['fit_sample_body', 'format_uncertainty_table', 'plot_corner', 'plot_spectra', 'sample_command_body'],
    },
)
