"""Spectra to colours: CIE XYZ, RGB, the paper's gamut mapping and colour shift.

The names the rest of the package uses, loaded on first use (``lazy_loader``).
"""

import lazy_loader

__getattr__, __dir__, __all__ = lazy_loader.attach(
    __name__,
    submod_attrs={
        "tristimulus": ['DEFAULT_OBSERVER', 'SpectralResamplingWarning', 'SpectralWeights', 'VISIBLE_NM', 'colour_science', 'observer_cmfs',
                        'spectral_weights', 'spectrum_to_XYZ', 'warn_outside_visible'],
        "rgb": ['RGBConversion', 'RGB_to_XYZ', 'XYZ_to_RGB', 'XYZ_to_display_RGB', 'encode_RGB', 'eotf_inverse_sRGB', 'rgb_conversion', 'spectrum_to_RGB'],
        "difference": ['XYZ_to_Lab', 'delta_E_CIE2000'],
        "chromaticity": ['XYZ_to_xy', 'dominant_wavelength', 'excitation_purity'],
        "colour_shift": ['average_normal_reflectance', 'colour_shift_approximation', 'colour_shift_spectral', 'colour_shift_weight',
                         'fresnel_reflectance_spectrum'],
        "gamut": ['desaturate_to_gamut', 'in_gamut', 'scale_to_display', 'srgb_luminance'],
        "report": ['colour_report', 'reflectance_spectrum'],
    },
)
