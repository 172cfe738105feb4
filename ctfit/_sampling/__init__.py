"""The posterior of a fit: emcee sampling, priors, checks, summaries, plots.

The names the rest of the package uses, loaded on first use (``lazy_loader``).
"""

import lazy_loader

__getattr__, __dir__, __all__ = lazy_loader.attach(
    __name__,
    submod_attrs={
        "chain_diagnostics": ['ChainTooShortWarning'],
        "emcee_run": ['MAX_SEED', 'MAX_STEPS', 'MAX_WALKERS', 'sample'],
        "plots": ['plot_corner', 'plot_spectra'],
        "posterior_density": ['log_probability'],
        "result": ['SampleResult'],
        "start": ['check_fitted_loss'],
        "table": ['format_uncertainty_table'],
    },
)
