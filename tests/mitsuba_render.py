"""BRDF samples rendered by Mitsuba 3 (`roughconductor`, Beckmann, Smith G, conductor Fresnel).

Mitsuba's ``eval(ctx, si, wo)`` returns f_r · cos θ(wo); we divide the cosine out. Each
wavelength gets its own BSDF with that wavelength's tabulated n and k (scalar_rgb variant with
constant spectra, so no RGB upsampling touches the values).
"""

import numpy as np

import ctfit


def render(n_pairs, wavelength_nm, n, k, m, *, max_theta, seed, noise=0.0):
    import mitsuba as mi

    mi.set_variant("scalar_rgb")
    ti, pi, to, po = ctfit.goniometer_directions(n_pairs, spread=2.5 * m, max_theta=max_theta, seed=seed)
    light = np.asarray(ctfit.direction_from_angles_deg(ti, pi))
    view = np.asarray(ctfit.direction_from_angles_deg(to, po))
    values = np.zeros((n_pairs, len(wavelength_nm)))
    ctx = mi.BSDFContext()
    for j in range(len(wavelength_nm)):
        bsdf = mi.load_dict({"type": "roughconductor", "distribution": "beckmann", "alpha": float(m),
                             "sample_visible": False, "eta": float(n[j]), "k": float(k[j])})
        for i in range(n_pairs):
            si = mi.SurfaceInteraction3f()
            si.wi = mi.Vector3f(*light[i])
            si.sh_frame = mi.Frame3f(mi.Vector3f(0, 0, 1))
            val = bsdf.eval(ctx, si, mi.Vector3f(*view[i]))
            values[i, j] = float(val[0]) / view[i, 2] if view[i, 2] > 0 else 0.0
    if noise:
        rng = np.random.default_rng([seed, 7])
        values = np.maximum(values * (1 + noise * rng.standard_normal(values.shape)), 0.0)
    nb = len(wavelength_nm)
    return ctfit.Measurement(
        theta_i=np.repeat(ti, nb), phi_i=np.repeat(pi, nb), theta_o=np.repeat(to, nb), phi_o=np.repeat(po, nb),
        band=np.tile(np.arange(nb), n_pairs), wavelength_nm=np.asarray(wavelength_nm, float),
        brdf=values.reshape(-1), source=f"<mitsuba roughconductor m={m}>",
    )
