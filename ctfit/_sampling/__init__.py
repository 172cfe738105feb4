"""The posterior of a fit: emcee sampling, priors, checks, summaries, plots.

The names the rest of the package uses, loaded on first use (``lazy_loader``).
"""

import lazy_loader

__getattr__, __dir__, __all__ = lazy_loader.attach(
    __name__,
    submod_attrs={
        "chain_diagnostics": ['ChainTooShortWarning'],
        "emcee_run": ['sample'],
        "plots": ['plot_corner', 'plot_spectra'],
        "posterior_density": ['log_probability'],
        "result": ['SampleResult'],
        "run_limits": ['MAX_SEED', 'MAX_STEPS', 'MAX_WALKERS'],
        "start": ['check_fitted_loss'],
        "table": ['format_uncertainty_table'],
    },
)
