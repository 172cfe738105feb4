"""A fitted material tabulated as a MERL ``.binary`` file: the model at every cell centre, in linear sRGB."""

from __future__ import annotations

import numpy as np

from .._io import angles_deg_to_half_diff_deg, half_diff_deg_to_angles_deg, merl_cell_centres, merl_phi_d_index, merl_theta_d_index, merl_theta_h_index
from .._model import Material, evaluate_at
from .rgb_bands import band_to_rgb, into_gamut

__all__ = ["merl_lookup", "merl_model_table"]


def merl_model_table(material: Material) -> tuple[np.ndarray, bool]:
    """The (3, 90, 90, 180) MERL table of the material (sr⁻¹; below the horizon 0), and whether
    a cell's colour was outside sRGB's gamut.

    Each cell holds the BRDF at its centre (``ctfit._io.merl``), per band, turned into linear
    sRGB by :func:`~ctfit._export.rgb_bands.band_to_rgb`. One θ_h row at a time. A colour with a
    negative channel (a spectrum outside sRGB's gamut) is desaturated into the gamut at constant
    luminance (:func:`~ctfit._export.rgb_bands.into_gamut`): a MERL file's negative value marks
    a cell that was not measured.

    Examples
    --------
    >>> import numpy as np, ctfit
    >>> from ctfit._export.merl_export import merl_model_table
    >>> matte = ctfit.Material(ctfit.Structure(lobes=0, diffuse="constant"), ctfit.Params(rd=np.array(0.1)), channels=("G",))
    >>> table, out_of_gamut = merl_model_table(matte)
    >>> out_of_gamut, table.shape, round(float(table[0, 10, 10, 10]), 6), round(float(table[2, 10, 89, 10]), 6)  # below the horizon: 0
    (False, (3, 90, 90, 180), 0.1, 0.0)
    """
    to_rgb = band_to_rgb(material)
    th, td, pd = (np.rad2deg(a) for a in merl_cell_centres())
    table = np.empty((90, 90, 180, 3))
    for i, theta_h in enumerate(th):
        ti, pi, to, po = half_diff_deg_to_angles_deg(theta_h, td[:, None], pd[None, :])
        table[i] = np.asarray(evaluate_at(material, theta_i=ti, phi_i=pi, theta_o=to, phi_o=po), float) @ to_rgb
    table, changed = into_gamut(table)
    return np.moveaxis(table, -1, 0), changed


def merl_lookup(table, theta_i, phi_i, theta_o, phi_o) -> np.ndarray:
    """(…, 3) values of a MERL table at directions in degrees: the cell each direction pair falls in.

    Examples
    --------
    >>> import numpy as np, ctfit
    >>> from ctfit._export.merl_export import merl_lookup
    >>> table = ctfit.merl_table(lambda theta_h, theta_d, phi_d: theta_d + 0 * theta_h + 0 * phi_d)
    >>> print(np.round(np.degrees(merl_lookup(table, 30.0, 0.0, 30.0, 180.0)), 2))  # θ_d = 30° in the cell 30–31°
    [30.5 30.5 30.5]
    """
    th, td, pd = (np.deg2rad(a) for a in angles_deg_to_half_diff_deg(theta_i, phi_i, theta_o, phi_o))
    i, j, k = merl_theta_h_index(th), merl_theta_d_index(td), merl_phi_d_index(pd)
    return np.moveaxis(np.asarray(table)[:, i, j, k], 0, -1)
