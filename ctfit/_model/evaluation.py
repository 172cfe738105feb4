"""Synthetic measurements: a goniometer-like sampling of the hemisphere, evaluated with the model.

The light takes incidence angles θ_i on an even grid in cos θ up to ``max_theta`` (azimuth 0).
For each light direction, viewer directions are drawn half uniformly over the projected
hemisphere (so grazing views are rarer, as on a real gonioreflectometer) and half around the
mirror direction (θ_i, 180°) with a spread of a few times the material's rms slope, where the
specular lobe needs dense sampling. Each direction pair is measured in every band.

Noise is relative and Gaussian: brdf_noisy = brdf · (1 + noise · ε), ε ~ N(0, 1), clipped at 0;
with noise > 0 the samples carry ``sigma = noise · max(brdf, 10⁻⁶ · max brdf)`` (the standard
uncertainty that was used, floored so that no sample gets an infinite weight). Everything is reproducible from ``seed`` (NumPy's PCG64).
"""

from __future__ import annotations

from collections.abc import Callable, Sequence

import jax
import jax.numpy as jnp
import numpy as np
from jax.typing import DTypeLike
from jaxtyping import Array, ArrayLike, Float

from .cook_torrance import brdf
from .directions import geometry, geometry_from_angles_deg
from .material import Material, Params, Structure
from .measurement import Measurement
from .numerics import x64_enabled

__all__ = ["simulate", "goniometer_directions", "evaluate", "evaluate_at", "by_blocks"]


def goniometer_directions(
    n_pairs: int, *, spread: float = 0.3, max_theta: float = 85.0, seed: int = 0
) -> tuple[Float[np.ndarray, " pairs"], Float[np.ndarray, " pairs"], Float[np.ndarray, " pairs"], Float[np.ndarray, " pairs"]]:
    """``n_pairs`` direction pairs (θ_i, φ_i, θ_o, φ_o) in degrees, denser near the mirror direction.

    ``spread`` is the rms angle (radians, as a slope) of the mirror-centred half of the sample.

    Examples
    --------
    The light takes a few incidence angles in the plane φ_i = 0; no angle exceeds ``max_theta``:

    >>> import ctfit
    >>> theta_i, phi_i, theta_o, phi_o = ctfit.goniometer_directions(200, max_theta=80.0, seed=1)
    >>> theta_i.shape, len(set(theta_i.tolist())), set(phi_i.tolist()), bool(theta_o.max() <= 80.0)
    ((200,), 3, {0.0}, True)
    """
    if n_pairs < 1:
        raise ValueError(f"n_pairs must be ≥ 1, got {n_pairs}")
    if not 0 < max_theta < 90:
        raise ValueError(f"max_theta must be in (0, 90) degrees, got {max_theta}")
    rng = np.random.default_rng(seed)
    n_light = max(1, min(18, int(round(np.sqrt(n_pairs / 20)))))
    cos_max = np.cos(np.deg2rad(max_theta))
    theta_l = np.rad2deg(np.arccos(np.linspace(1.0, cos_max, n_light + 1)[:-1] - 0.5 * (1 - cos_max) / n_light))
    theta_i = theta_l[np.arange(n_pairs) % n_light]
    rng.shuffle(theta_i)
    n_uniform = n_pairs // 2
    # Uniform over the projected hemisphere, truncated at max_theta.
    r = np.sqrt(rng.uniform(0, 1, n_uniform)) * np.sin(np.deg2rad(max_theta))
    theta_u = np.rad2deg(np.arcsin(r))
    phi_u = rng.uniform(0, 360, n_uniform)
    # Around the mirror direction: Gaussian slopes of the half vector, then reflect.
    n_mirror = n_pairs - n_uniform
    ti = np.deg2rad(theta_i[n_uniform:])
    light = np.stack([np.sin(ti), np.zeros_like(ti), np.cos(ti)], axis=1)
    slopes = rng.normal(0, spread, (n_mirror, 2))
    h = np.concatenate([-slopes, np.ones((n_mirror, 1))], axis=1)
    h /= np.linalg.norm(h, axis=1, keepdims=True)
    view = 2 * np.sum(light * h, axis=1, keepdims=True) * h - light
    view[:, 2] = np.maximum(view[:, 2], np.cos(np.deg2rad(max_theta)))
    view /= np.linalg.norm(view, axis=1, keepdims=True)
    theta_m = np.rad2deg(np.arccos(np.clip(view[:, 2], -1, 1)))
    phi_m = np.rad2deg(np.arctan2(view[:, 1], view[:, 0])) % 360
    theta_o = np.concatenate([theta_u, theta_m])
    phi_o = np.concatenate([phi_u, phi_m])
    return theta_i, np.zeros(n_pairs), np.minimum(theta_o, max_theta), phi_o


def _spread(material: Material) -> float:
    p = material.params
    if material.structure.lobes == 0 or p.m is None:
        return 0.5
    return float(np.clip(2.5 * np.max(np.asarray(p.m)), 0.02, 0.8))


def evaluate(material: Material, measurement: Measurement, *, dtype: DTypeLike | None = None) -> Float[np.ndarray, " samples"]:
    """The material's BRDF at every sample of ``measurement`` (sr⁻¹), as a NumPy array (N,).

    Per-band parameters are resampled to the measurement's bands (linear interpolation in λ,
    held at the ends) or picked by channel name. Computed in float64 when JAX has x64 enabled,
    else float32 (or ``dtype`` if given).

    Examples
    --------
    F0 given at 400 and 700 nm is 0.5 at the measurement's 550 nm, so a diffuse material with
    R_d = F0/π gives 0.5/π in every direction:

    >>> import numpy as np, ctfit
    >>> paint = ctfit.Material(ctfit.Structure(lobes=0, diffuse="F0/pi"), ctfit.Params(f0=np.array([0.2, 0.8])),
    ...                        wavelength_nm=np.array([400.0, 700.0]))
    >>> samples = ctfit.Measurement(theta_i=np.array([0.0, 60.0]), phi_i=np.zeros(2), theta_o=np.array([30.0, 10.0]),
    ...                             phi_o=np.zeros(2), band=np.zeros(2, int), wavelength_nm=np.array([550.0]))
    >>> np.asarray(np.pi * ctfit.evaluate(paint, samples), float).round(6).tolist()
    [0.5, 0.5]
    """
    if material.band_unknown and not measurement.band_unknown:
        raise ValueError(f"material {material.name!r} has one band of unknown wavelength (band_unknown); it has no values at the bands of "
                         f"{measurement.source or 'the data'} ({', '.join(measurement.band_labels[:4])}{', …' if measurement.n_bands > 4 else ''}): "
                         "evaluate it on data of that one band")
    params = _checked(material, dtype).params_at(measurement.wavelength_nm if measurement.channels is None else None, measurement.channels)
    pairs, index = measurement.directions()
    dt = dtype or (jnp.float64 if x64_enabled() else jnp.float32)
    params = jax.tree.map(lambda a: jnp.asarray(a, dtype=dt), params)
    values = by_blocks(lambda block: _grid_values(material.structure, params, block), np.asarray(pairs, dtype=dt), _NORMAL_PAIR)
    return values[index, measurement.band if values.shape[1] > 1 else 0]  # one column: no parameter per band, every band alike


def _checked(material: Material, dtype: DTypeLike | None) -> Material:
    """``material``, checked to be a :class:`Material` whose parameters fit its structure, and
    ``dtype`` a float type (an integer one gave NaN everywhere)."""
    if not isinstance(material, Material):
        hint = " (read a file with ctfit.load_material(path))" if isinstance(material, (str, bytes)) or hasattr(material, "__fspath__") else ""
        raise TypeError(f"material must be a ctfit.Material, got {type(material).__name__}{hint}")
    if dtype is not None and not jnp.issubdtype(dtype, jnp.floating):
        raise ValueError(f"dtype must be a float type (float32 or float64), got {np.dtype(dtype).name}")
    return material.check_shapes()


def evaluate_at(
    material: Material,
    *,
    theta_i: Float[ArrayLike, "*#batch"] | None = None,
    phi_i: Float[ArrayLike, "*#batch"] = 0.0,
    theta_o: Float[ArrayLike, "*#batch"] | None = None,
    phi_o: Float[ArrayLike, "*#batch"] = 0.0,
    l: Float[ArrayLike, "*#batch 3"] | None = None,
    v: Float[ArrayLike, "*#batch 3"] | None = None,
    wavelength_nm: Float[ArrayLike, " bands"] | None = None,
    dtype: DTypeLike | None = None,
) -> Float[np.ndarray, "*batch bands"]:
    """The material's BRDF (sr⁻¹) at any directions, in every band: no :class:`Measurement` needed.

    Directions are angles in degrees — ``theta_i``, ``phi_i`` (light), ``theta_o``, ``phi_o``
    (viewer), broadcast together — or unit vectors ``l`` (to the light) and ``v`` (to the
    viewer), shape (..., 3), normal +z (``docs/conventions.md``). Bands: the material's own, or
    ``wavelength_nm`` (interpolated as :meth:`Material.params_at` does; spectral materials).
    Returns shape ``directions + (bands,)``; directions at or below the horizon give 0. A NaN or
    infinite direction, a vector whose length is not 1 (to 10⁻³) or a wavelength that is not a
    positive number raises ``ValueError``, naming it. One structure compiles at most three
    programs, whatever the number of directions (:data:`EVAL_BLOCK`). The values come back as
    NumPy, computed by compiled programs: to differentiate, trace :func:`ctfit.brdf` (with
    :func:`ctfit.geometry_from_angles_deg`), which ``jax.grad`` goes through in every parameter.

    >>> import numpy as np, ctfit
    >>> gold = ctfit.Material(ctfit.Structure(lobes=1), ctfit.Params(m=np.array([0.2]), w=np.ones(1), f0=np.array([0.4, 0.9])),
    ...                       wavelength_nm=np.array([450.0, 650.0]))
    >>> ctfit.evaluate_at(gold, theta_i=30.0, theta_o=[0.0, 30.0, 60.0], phi_o=180.0).shape
    (3, 2)
    """
    by_angles = theta_i is not None or theta_o is not None
    if by_angles == (l is not None or v is not None) or (by_angles and (theta_i is None or theta_o is None)) or (not by_angles and (l is None or v is None)):
        raise ValueError("give the directions either as angles (theta_i and theta_o, with phi_i, phi_o) or as unit vectors (l and v)")
    if wavelength_nm is not None and material.wavelength_nm is None:
        raise ValueError(f"material {material.name!r} has RGB channels; it has no values at wavelengths")
    wl = None if wavelength_nm is None else np.asarray(wavelength_nm, dtype=float)
    if wl is not None and not np.all(np.isfinite(wl) & (wl > 0)):
        raise ValueError(f"wavelength_nm must be positive finite numbers of nm, got {np.asarray(wavelength_nm).tolist()!r}")
    params = _checked(material, dtype).params_at(wavelength_nm)
    dt = dtype or (jnp.float64 if x64_enabled() else jnp.float32)
    params = jax.tree.map(lambda a: jnp.asarray(a, dtype=dt), params)
    pad: tuple[float, ...]
    if by_angles:
        given = [np.asarray(a, dtype=float) for a in (theta_i, phi_i, theta_o, phi_o)]
        try:
            angles = np.broadcast_arrays(*given)
        except ValueError:
            shapes = ", ".join(f"{name} {a.shape}" for name, a in zip(("theta_i", "phi_i", "theta_o", "phi_o"), given))
            raise ValueError(f"the angles must broadcast together (NumPy's rules), got shapes {shapes}") from None
        for name, a in zip(("theta_i", "phi_i", "theta_o", "phi_o"), angles):
            _check_finite(name, a)
        shape, rows, run, pad = angles[0].shape, np.stack([a.reshape(-1) for a in angles], axis=1), _grid_values, _NORMAL_PAIR
    else:
        try:
            lv = np.broadcast_arrays(np.asarray(l, dtype=float), np.asarray(v, dtype=float))
        except ValueError:
            raise ValueError(f"l and v must broadcast together, got shapes {np.asarray(l).shape} and {np.asarray(v).shape}") from None
        if lv[0].shape[-1:] != (3,):
            raise ValueError(f"l and v must be unit vectors of shape (..., 3), got shapes {np.shape(lv[0])} and {np.shape(lv[1])}")
        for name, a in zip("lv", lv):
            _check_finite(name, a)
            length = np.linalg.norm(a, axis=-1)
            if np.any(np.abs(length - 1) > 1e-3):  # (rounded input, 0.866 for √3/2, passes; a vector not normalised does not)
                at = np.unravel_index(np.argmax(np.abs(length - 1)), length.shape)
                raise ValueError(f"{name} must be unit vectors: |{name}{_index(at)}| = {float(length[at]):.6g}")
        shape, rows, run, pad = lv[0].shape[:-1], np.concatenate([a.reshape(-1, 3) for a in lv], axis=1), _vector_values, _NORMAL_VECTORS
    values = by_blocks(lambda block: run(material.structure, params, block), rows.astype(dt), pad)
    if values.shape[-1] == 1:  # no parameter per band (an R_d of one number): every band of the material (or of wl) alike
        bands = wl.size if wl is not None else len(material.band_labels)  # (none for a material of neither wavelengths nor channels)
        values = np.repeat(values, max(bands, 1), axis=-1)
    return values.reshape(*shape, values.shape[-1])


def _check_finite(name: str, a: np.ndarray) -> None:
    if not np.all(np.isfinite(a)):
        at = np.unravel_index(np.argmin(np.isfinite(a)), a.shape)
        raise ValueError(f"{name}{_index(at)} is {a[at]}: directions must be finite numbers")


def _index(at: tuple) -> str:
    return f"[{', '.join(str(int(i)) for i in at)}]" if at else ""


EVAL_BLOCK = 8192
"""Direction pairs per call of the compiled model in :func:`evaluate` and :func:`evaluate_at`.
Fewer are padded to 512 or 2,048 (or this), more are cut into blocks of this many: one structure
compiles at most three programs (per bands and dtype) whatever the number of directions, where a
program per size cost 0.3 s of compiling each, and its memory maps (a process is allowed 65,530;
a program takes a few dozen), which a loop over files of many sizes ran out of."""

_NORMAL_PAIR = (0.0, 0.0, 0.0, 0.0)  # padding rows: light and viewer at the normal (θ_i, φ_i, θ_o, φ_o)
_NORMAL_VECTORS = (0.0, 0.0, 1.0, 0.0, 0.0, 1.0)  # (l, v) at the normal


def _block_rows(n: int) -> int:
    """The padded size of a call of ``n`` rows: 512, 2,048 or :data:`EVAL_BLOCK`."""
    size = 512
    while size < min(n, EVAL_BLOCK):
        size *= 4
    return min(size, EVAL_BLOCK)


def by_blocks(run: Callable[[np.ndarray], Array], rows: np.ndarray, pad: tuple[float, ...]) -> np.ndarray:
    """``run(block)`` over ``rows`` (n, k) in blocks of 512, 2,048 or :data:`EVAL_BLOCK` rows, the
    last one padded with rows ``pad``: a compiled ``run`` sees at most three shapes, whatever n.
    Its results (one row per row) concatenated, the padding dropped, as NumPy."""
    n = rows.shape[0]
    size = _block_rows(n)
    total = -(-max(n, 1) // size) * size
    padded = np.concatenate([rows, np.broadcast_to(np.asarray(pad, rows.dtype), (total - n, rows.shape[1]))])
    blocks = [run(padded[at: at + size]) for at in range(0, total, size)]  # queued, then fetched
    return np.concatenate([np.asarray(b) for b in blocks])[:n]


def _grid_values_impl(structure: Structure, params: Params, pairs: Float[Array, "pairs 4"]) -> Float[Array, "pairs bands"]:
    geom = geometry_from_angles_deg(pairs[:, 0], pairs[:, 1], pairs[:, 2], pairs[:, 3])
    return brdf(structure, params, geom)


_grid_values = jax.jit(_grid_values_impl, static_argnums=0)


def _vector_values_impl(structure: Structure, params: Params, lv: Float[Array, "pairs 6"]) -> Float[Array, "pairs bands"]:
    return brdf(structure, params, geometry(lv[:, :3], lv[:, 3:]))


_vector_values = jax.jit(_vector_values_impl, static_argnums=0)


def simulate(
    material: Material,
    n_pairs: int = 2000,
    *,
    wavelength_nm: Float[ArrayLike, " bands"] | None = None,
    channels: Sequence[str] | None = None,
    noise: float = 0.0,
    seed: int = 0,
    max_theta: float = 85.0,
) -> Measurement:
    """Synthetic measurement of ``material``: ``n_pairs`` direction pairs × every band.

    Bands: ``wavelength_nm`` (default: the material's own wavelengths restricted to
    400–700 nm, or 400–700 nm every 10 nm if it lists none there), or the material's channels
    for RGB materials.

    Examples
    --------
    >>> import numpy as np, ctfit
    >>> copper = ctfit.Material(ctfit.Structure(), ctfit.Params(m=np.array([0.4]), w=np.array([1.0]),
    ...                         f0=np.array([0.95, 0.64, 0.54])), channels=("R", "G", "B"))
    >>> exact = ctfit.simulate(copper, 100)  # 100 direction pairs × 3 channels
    >>> len(exact), exact.band_labels
    (300, ['R', 'G', 'B'])
    >>> noisy = ctfit.simulate(copper, 100, noise=0.05)  # the same directions, brdf × (1 + 0.05 ε)
    >>> print(f"{np.std(noisy.brdf / exact.brdf - 1):.2f}")
    0.05
    """
    if isinstance(noise, (bool, np.bool_)) or not isinstance(noise, (int, float, np.integer, np.floating)) or not 0 <= noise < np.inf:
        raise ValueError(f"noise must be a finite number ≥ 0, got {noise!r}")
    for name, value in (("n_pairs", n_pairs), ("seed", seed)):
        if isinstance(value, bool) or not isinstance(value, (int, np.integer)):
            raise ValueError(f"{name} must be a whole number, got {value!r}")
    if seed < 0:
        raise ValueError(f"seed must be ≥ 0 (NumPy's generators take no negative seed), got seed={seed}")
    if material.is_rgb and wavelength_nm is not None:
        raise ValueError(f"material {material.name!r} has RGB channels; it has no values at wavelength_nm")
    if not material.is_rgb and channels is not None:
        raise ValueError(f"material {material.name!r} is spectral; channels name the bands of an RGB material")
    if material.is_rgb:
        channels = tuple(channels or material.channels or ())
        wl = None
    elif material.band_unknown:  # one band of unknown wavelength (a fit of an ALTA file): that band, as the data had it
        if wavelength_nm is not None:
            raise ValueError(f"material {material.name!r} has one band of unknown wavelength (band_unknown); it has no values at "
                             "wavelength_nm: simulate it without wavelengths")
        wl, channels = np.asarray(material.wavelength_nm, dtype=float), None
    else:
        if wavelength_nm is None:
            own = np.asarray(material.wavelength_nm, dtype=float)
            sel = own[(own >= 400) & (own <= 700)]
            wavelength_nm = sel if len(sel) else np.arange(400.0, 701.0, 10.0)
        wl = np.unique(np.asarray(wavelength_nm, dtype=float).reshape(-1))
        if wl.size == 0 or not np.all(np.isfinite(wl) & (wl > 0)):
            raise ValueError(f"wavelength_nm must be positive finite numbers of nm, got {np.asarray(wavelength_nm).tolist()!r}")
        channels = None
    ti, pi, to, po = goniometer_directions(n_pairs, spread=_spread(material), max_theta=max_theta, seed=seed)
    n_bands = len(channels) if channels is not None else len(wl if wl is not None else ())
    rep = lambda a: np.repeat(a, n_bands)
    band = np.tile(np.arange(n_bands), n_pairs)
    base = Measurement(
        theta_i=rep(ti), phi_i=rep(pi), theta_o=rep(to), phi_o=rep(po), band=band,
        wavelength_nm=wl, channels=channels,
        meta={"source": "ctfit simulate", "material": material.name or "", "seed": str(seed), "noise": f"{noise:g}"},
        source="<simulated>", band_unknown=material.band_unknown,
    )
    truth = evaluate(material, base)
    sigma = None
    values = truth
    if noise > 0:
        rng = np.random.default_rng([seed, 1])
        with np.errstate(over="ignore"):
            values = np.maximum(truth * (1 + noise * rng.standard_normal(truth.shape)), 0.0)
            sigma = noise * np.maximum(truth, max(1e-6 * float(np.max(truth)), np.finfo(float).tiny))  # > 0 even where the truth is 0 everywhere
        if not (np.all(np.isfinite(values)) and np.all(np.isfinite(sigma))):
            raise ValueError(f"noise={noise:g} is too large: the noisy values overflow")
    return base.replace(brdf=values, sigma=sigma)
