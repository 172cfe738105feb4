"""The free coordinates of a fit: the map between a problem's free values ``u`` and the model's
:class:`~ctfit.Params`, their bounds, and which parameters a structure frees.

Free parameters live in a pytree ``u`` (a dict) of coordinates from the one parameter table
(:mod:`ctfit._model.parameters`). A problem's ``spec.space`` says which:

- "box" (the fit): s, F0, n, k, R_d themselves, log m, and stick-breaking fractions of the
  lobe weights (:func:`lobe_weights`), each inside closed bounds that the projected
  Levenberg–Marquardt solver keeps; a parameter may end on its bound (s = 1, F0 = 0, a weight 0).
- "unconstrained" (the sampler): m = exp(u), w = softmax(0, u), s and F0 = sigmoid(u),
  n = n_min + softplus(u), k and R_d = softplus(u).

Parameters not free are taken from ``fixed`` (a :class:`~ctfit.Params`). Parameters the
structure does not have are not in ``u`` at all.
"""

from __future__ import annotations

from typing import TYPE_CHECKING

import jax
import jax.numpy as jnp
import numpy as np

from .._model import Params, Structure, array_module, box_bounds, clip_box, n_lower, parameter

if TYPE_CHECKING:
    from .problem import Spec

__all__ = ["lobe_weights", "weight_coordinates", "fraction_weights", "stick_fractions", "to_params", "from_params", "bounds", "free_names", "flat_host"]


def lobe_weights(u_w, space: str, xp=jnp):
    """Lobe weights from J − 1 free values (see the module docstring); ``xp``: ``jax.numpy``
    (traceable) or ``numpy`` (on the host: box coordinates, as :func:`to_params` takes them there).

    Box: stick-breaking fractions v ∈ [0, 1]^(J−1), w_0 = 1 − v_1, w_j = v_1⋯v_j (1 − v_(j+1)),
    w_(J−1) = v_1⋯v_(J−1): every lobe's weight reaches 0 on a bound of the box."""
    if space == "box":
        ones = xp.ones((1,), u_w.dtype)
        return xp.cumprod(xp.concatenate([ones, u_w])) * xp.concatenate([1 - u_w, ones])
    return jax.nn.softmax(jnp.concatenate([jnp.zeros((1,), u_w.dtype), u_w]))


def stick_fractions(w) -> np.ndarray:
    """Inverse of the box map of :func:`lobe_weights` on the host (NumPy, no program), for any
    non-negative ``w`` (normalised here): v_j = (Σ_(i≥j) w_i) / (Σ_(i≥j−1) w_i)."""
    w = np.clip(np.asarray(w, dtype=float), 0, None)
    return weight_coordinates(w / np.sum(w), "box", np)


def weight_coordinates(w, space: str, xp=jnp):
    """Inverse of :func:`lobe_weights`: the J − 1 free values of lobe weights ``w`` (Σ w = 1; a
    leading batch axis allowed), stick-breaking fractions v_j = (Σ_(i≥j) w_i) / (Σ_(i≥j−1) w_i)
    in the box, log ratios to the first lobe's weight otherwise; ``xp``: ``jax.numpy`` (traceable)
    or ``numpy`` (on the host)."""
    if space == "box":
        rest = xp.flip(xp.cumsum(xp.flip(w, axis=-1), axis=-1), axis=-1)  # Σ_(i≥j) w_i
        return xp.clip(rest[..., 1:] / xp.maximum(rest[..., :-1], xp.finfo(w.dtype).tiny), 0.0, 1.0)
    return xp.log(w[..., 1:]) - xp.log(w[..., :1])


def fraction_weights(v) -> np.ndarray:
    """:func:`lobe_weights` of box coordinates on the host (NumPy, no program): the lobes' weights
    of the stick-breaking fractions ``v`` (J − 1 of them); :func:`stick_fractions` inverts it."""
    return lobe_weights(np.asarray(v, dtype=float), "box", np)


def to_params(spec: Spec, u: dict, fixed: Params, xp=jnp) -> Params:
    """Model parameters from the free coordinates ``u`` (``spec.space``: "box" or "unconstrained").
    ``xp``: ``jax.numpy`` (traceable), or ``numpy`` for box coordinates on the host (no program).

    Box coordinates are held inside their bounds (:func:`~ctfit._model.parameters.clip_box`), so any
    solver's trial point gives a valid model; the projected solver never leaves them anyway.
    """
    st = spec.structure
    if xp is not jnp and spec.space != "box":
        raise ValueError("to_params on the host (xp=numpy) takes box coordinates only")

    def pick(name):
        if name not in u:
            return getattr(fixed, name)
        row = parameter(name)
        if spec.space == "box":
            lo, hi = box_bounds(name, st.fresnel, st.family)
            value = row.box(clip_box(u[name], lo, hi))
        else:
            value = (n_lower(st.fresnel, st.family) if name == "n" else 0.0) + row.free(u[name])
        if name == "n" and st.shared_index:  # a plastic: one free index, the same in every band
            value = xp.broadcast_to(value, np.shape(fixed.n))
        return value

    w = None
    if st.has_specular:
        if "w" in u:
            w = lobe_weights(clip_box(u["w"], *box_bounds("w")) if spec.space == "box" else u["w"], spec.space, xp)
        elif st.lobes == 1 and fixed.w is None:
            w = xp.ones((1,), u["m"].dtype if "m" in u else jnp.result_type(float))
        else:
            w = fixed.w
    return Params(
        s=pick("s") if st.has_s else None,
        m=pick("m") if st.has_specular else None,
        w=w,
        f0=pick("f0") if st.fresnel == "f0" and st.needs_fresnel_params else None,
        n=pick("n") if st.fresnel != "f0" and st.needs_fresnel_params else None,
        k=pick("k") if st.fresnel == "conductor" and st.needs_fresnel_params else None,
        rd=pick("rd") if st.has_rd else None,
    )


def from_params(spec: Spec, params: Params) -> dict:
    """Free coordinates ``u`` of ``params`` (inverse of :func:`to_params`; box coordinates are
    clipped into their bounds)."""
    u = {}
    for name in spec.free:
        v = np.asarray(getattr(params, name), dtype=float)
        row = parameter(name)
        if name == "w":
            v = np.clip(v, 1e-12, None)
            u[name] = weight_coordinates(v / np.sum(v), spec.space, np)
            continue
        if name == "n" and spec.structure.shared_index:
            v = np.asarray(np.mean(v))  # a plastic's one index
        if spec.space == "box":
            lo, hi = box_bounds(name, spec.structure.fresnel, spec.structure.family)
            u[name] = np.clip(row.box_inverse(np.maximum(v, 1e-300) if name == "m" else v), lo, hi)
        else:
            offset = n_lower(spec.structure.fresnel, spec.structure.family) if name == "n" else 0.0
            u[name] = row.free_inverse(v - offset)
    return u


def bounds(spec: Spec, u: dict) -> tuple[dict, dict]:
    """Lower and upper bounds of the box coordinates ``u`` (same pytree, arrays of u's shapes;
    NumPy for NumPy ``u``)."""
    xp = array_module(*u.values())
    lo, hi = {}, {}
    for name, v in u.items():
        a, b = box_bounds(name, spec.structure.fresnel, spec.structure.family)
        lo[name] = xp.full(xp.shape(v), a, xp.result_type(v))
        hi[name] = xp.full(xp.shape(v), b, xp.result_type(v))
    return lo, hi


def free_names(structure: Structure, fixed: tuple[str, ...] = ()) -> tuple[str, ...]:
    """The parameters a structure has, minus those held fixed, in a canonical order."""
    names = []
    if structure.has_s:
        names.append("s")
    if structure.has_specular:
        names.append("m")
        if structure.lobes > 1:
            names.append("w")
    if structure.needs_fresnel_params:
        names += ["f0"] if structure.fresnel == "f0" else (["n", "k"] if structure.fresnel == "conductor" else ["n"])
    if structure.has_rd:
        names.append("rd")
    return tuple(n for n in names if n not in fixed)


def flat_host(tree: dict, batch: bool = False) -> np.ndarray:
    """``ravel_pytree``'s flat order (sorted names, each entry flattened) of host arrays, on the host
    (``ravel_pytree`` of NumPy arrays would make a program); ``batch``: of each row along a leading axis."""
    lead = (next(iter(tree.values())).shape[0],) if batch else ()
    return np.concatenate([np.reshape(tree[name], lead + (-1,)) for name in sorted(tree)], axis=-1)
