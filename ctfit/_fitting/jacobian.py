"""The residual's Jacobian in factored form, the normal equations built from it, and the
residual with a custom JVP.

The residual's Jacobian has structure that a generic Jacobian ignores: R = s F(λ) S(m, w) +
(1 − s) R_d(λ), where S (the D·G lobe sum) depends only on the direction and F only on V·H and
the band. :func:`residual` therefore has a ``jax.custom_jvp`` that computes, once per
evaluation, ∂S/∂(m, w) per *direction* and the derivative of each value with respect to its own
band's parameters, and forms any Jacobian–vector product as a cheap contraction of these
columns. ``jax.linearize`` (used by optimistix's Gauss–Newton family) then costs a few model
passes instead of one per parameter; :func:`normal_equations` forms ½‖r‖², Jᵀr and JᵀJ from the
same columns, never an N × P matrix of the whole data.
"""

from __future__ import annotations

from typing import Any

import jax
import jax.numpy as jnp

from .chunks import sum_over_chunks
from .losses import loss_residuals
from .problem import Problem, at_samples, band_sum, model_values, per_direction, shape_and_rest, values_from_s

__all__ = ["DENSE_BAND_COLUMNS", "normal_equations", "normal_equations_and_values", "half_squared_norm", "residual"]


def _columns(problem: Problem, u: dict, y):
    """The residual and its Jacobian in factored form, all in the problem's layout.

    Returns ``(res, values, cols)`` with ``res`` the flat residual and ``cols`` a dict name →
    (kind, column): kind "shape" → (a, J_S) with ∂r/∂u_name = a · J_S[direction] (``a`` per
    sample, ``J_S`` (D, size) per direction); kind "scalar" → c with ∂r/∂u_name = c; kind "band"
    → e with ∂r_i/∂u_name[band_i] = e_i (a value depends only on its own band's entry).
    One model pass, one batched JVP for the band and scalar parameters and ∂/∂S, and a
    per-direction Jacobian of S — never an N × P matrix.
    """
    spec = problem.spec
    u_shape, u_rest = shape_and_rest(u)
    has_spec = spec.structure.has_specular
    s_dir: Any = per_direction(problem, u_shape, u_rest) if has_spec else None

    def f_rest(s, ur):
        return values_from_s(problem, s, ur, u_shape)

    # ∂v/∂S (tangent 1 on S) and ∂v/∂u_k for every band/scalar parameter k (tangent 1 on all
    # of u_k: each value sees only its own entry), one JVP each.
    names = tuple(sorted(u_rest))
    zeros = {n: jnp.zeros_like(v) for n, v in u_rest.items()}
    values = f_rest(s_dir, u_rest)
    dvs: dict[str, Any] = {}
    if has_spec and u_shape:
        dvs["__S__"] = jax.jvp(lambda s: f_rest(s, u_rest), (s_dir,), (jnp.ones_like(s_dir),))[1]
    for k in names:
        dvs[k] = jax.jvp(lambda ur: f_rest(s_dir, ur), (u_rest,), (dict(zeros, **{k: jnp.ones_like(u_rest[k])}),))[1]
    res, g = jax.jvp(lambda v: loss_residuals(problem, v, y, flat=False), (values,), (jnp.ones_like(values),))
    res, g = _barrier(res, g)  # the loss and its derivative once, not inside every column that reads them
    cols: dict[str, Any] = {}  # name → (kind, column)
    if "__S__" in dvs:
        a = g * dvs["__S__"]
        jac_s = jax.jacfwd(lambda us: per_direction(problem, us, u_rest))(u_shape)
        for k in u_shape:
            cols[k] = ("shape", (a, jac_s[k].reshape(s_dir.shape[0], -1)))
    for k in names:
        kind = "scalar" if jnp.ndim(u_rest[k]) == 0 else "band"
        cols[k] = (kind, g * dvs[k])
    return res.reshape(-1), values, cols


def normal_equations(problem: Problem, u: dict, *, dense: bool = False):
    """½‖r‖², Jᵀr and JᵀJ at ``u``, from the factored Jacobian (no N × P matrix), summed chunk by
    chunk for a large grid (:func:`sum_over_chunks`); see :func:`_normal_equations` (``dense``:
    one product of the stacked columns where the band columns are few)."""
    return sum_over_chunks(problem, lambda part: _normal_equations(part, u, dense))


def normal_equations_and_values(problem: Problem, u: dict, *, dense: bool = False):
    """(½‖r‖², Jᵀr, JᵀJ, the model's values) of one chunk ``problem`` (no sum over chunks): what
    :func:`_normal_equations` gives, and the model's values in the problem's layout, which its
    pass computes anyway (the fit's residual summary is made from them, on the host: no program
    of its own)."""
    res, values, cols = _columns(problem, u, problem.y)
    res, cols, values = _fenced(res, cols, values)
    return (*_normal_equations_from(problem, res, cols, sorted(u), dense), values)


def half_squared_norm(problem: Problem, u: dict):
    """½‖r‖² at ``u``, summed chunk by chunk for a large grid (:func:`sum_over_chunks`)."""

    def one(part):
        r = _residual(u, part.y, part)
        return 0.5 * jnp.sum(r * r)

    return sum_over_chunks(problem, one)


DENSE_BAND_COLUMNS = 12
"""With ``dense``, the normal equations are one product JᵀJ of the stacked Jacobian columns while
the band parameters' columns number at most this many (RGB: 3 per parameter); beyond (spectra),
they are formed block by block (:func:`_normal_equations`)."""


def _normal_equations(problem: Problem, u: dict, dense: bool = False):
    """½‖r‖², Jᵀr and JᵀJ at ``u``, from the factored Jacobian (:func:`_columns`; no N × P matrix
    of the whole data).

    The flat parameter order is that of ``jax.flatten_util.ravel_pytree(u)`` (sorted names,
    each entry flattened). By blocks (:func:`_blocks`): shape–shape J_Sᵀ diag(Σ_band a²) J_S;
    anything × band is a per-band sum; band × band is diagonal. With ``dense`` and few bands
    (:data:`DENSE_BAND_COLUMNS`), the columns are stacked instead (a shape parameter's J_S
    spread to its direction's samples, a band parameter's column to one column per band: N × P
    for the N samples of a chunk) and multiplied at once: one JᵀJ. The fit's chunk kernel
    (``chunked_fit.py``, a stored program every process loads) takes that form: its program
    has a fifth of the instructions, loads 3–4× and compiles ~1.4× faster, and runs faster on
    its chunks; with more band columns, on samples (not a grid), it takes :func:`_packed`, which
    compiles in about half the time of the blocks and runs about as fast. A fit of many small
    problems at once (texels, a folder's files of one geometry), compiled once and run long,
    takes the blocks, faster there (1,710 against 1,360 texels per second, float32; 4 % on 256
    files of 31 bands against :func:`_packed`). The columns are made once, then read by the
    products (:func:`_fenced`).
    """
    res, _, cols = _columns(problem, u, problem.y)
    res, cols = _fenced(res, cols)
    return _normal_equations_from(problem, res, cols, sorted(u), dense)


def _normal_equations_from(problem: Problem, res, cols: dict, names: list[str], dense: bool):
    """½‖r‖², Jᵀr and JᵀJ from the residual ``res`` and the factored columns ``cols``
    (:func:`_columns`) of the parameters ``names`` (sorted)."""
    banded = sum(problem.fixed_bands for k in names if cols[k][0] == "band")
    if dense and banded <= DENSE_BAND_COLUMNS:
        jac = jnp.concatenate([_spread(problem, *cols[k]).reshape(res.shape[0], -1) for k in names] or [jnp.zeros((res.shape[0], 0), res.dtype)], axis=1)
        return 0.5 * jnp.sum(res * res), jac.T @ res, jac.T @ jac
    blocks = _packed if dense and not problem.spec.grid else _blocks
    grad, hess = blocks(problem, res.reshape(problem.y.shape), cols, names)
    return 0.5 * jnp.sum(res * res), grad, hess


def _barrier(first, *rest):
    """``first`` and the pytrees ``rest`` as computed, fenced off from what reads them. XLA fuses
    elementwise work into every consumer that reads it, and removes an ``optimization_barrier``
    before it fuses; the result of a conditional is a buffer that fusion does not cross. Its
    predicate is data (whether the first entry of ``first`` is NaN), and both branches return
    the same values."""
    flat = jnp.reshape(first, (-1,))
    nan = jnp.isnan(flat[0]) if flat.shape[0] else jnp.asarray(False)
    return jax.lax.cond(nan, lambda x: jax.tree.map(lambda a: a * 1, x), lambda x: x, (first, *rest))


def _fenced(res, cols: dict, *more):
    """``res`` and the columns ``cols`` of :func:`_columns` (and any arrays ``more``) as computed,
    fenced off from the products that read them (:func:`_barrier`). Unfenced, XLA made each
    column inside every product that reads it: the normal equations of a chunk of 2,048 samples
    (31 bands, two lobes) did 4.0 MFLOP where the columns and the products take 1.2, and took
    0.39 ms instead of 0.21 ms."""
    res, arrays, *more = _barrier(res, {k: col for k, (_, col) in cols.items()}, *more)
    return res, {k: (kind, arrays[k]) for k, (kind, _) in cols.items()}, *more


def _packed(problem: Problem, r, cols: dict, names: list[str]):
    """(Jᵀr, JᵀJ) of a layout of samples (not a grid) from the factored columns, in two kinds of
    product: the columns of the shape and scalar parameters at every sample, stacked (``C``,
    N × q), give CᵀC and Cᵀr in one product each; every sum over a band's samples (the band
    parameters' Jᵀr, their products with ``C`` and with each other) is one :func:`band_sum` of
    those products stacked side by side.
    :func:`_blocks` forms the same block by block (a sum per block: 16 for 4 names), which runs
    as fast but compiles slower: 1.1 s against 0.65 s for a chunk of 2,048 samples of 31 bands
    (F0 per band, two lobes), 1.6 s against 0.8 s with n, k and R_d per band of RGB; a fit
    compiles one such program per structure it tries (``scripts/compile_times.py``). On a grid,
    :func:`_blocks` is as fast to compile and faster to run (it forms the shape columns' products
    per direction, not per value)."""
    W, n = problem.fixed_bands, r.shape[0]
    banded = [k for k in names if cols[k][0] == "band"]  # some: called with more than DENSE_BAND_COLUMNS of them
    spread = {k: _spread(problem, *cols[k]) for k in names if cols[k][0] != "band"}  # (N, size) each
    where, at = {}, 0
    for k, col in spread.items():
        where[k], at = slice(at, at + col.shape[1]), at + col.shape[1]
    c = jnp.concatenate(list(spread.values()), axis=1) if spread else jnp.zeros((n, 0), r.dtype)
    e = jnp.stack([cols[k][1] for k in banded], axis=1)
    q, nb = c.shape[1], e.shape[1]
    parts = [e * r[:, None], (e[:, :, None] * c[:, None, :]).reshape(n, nb * q), (e[:, :, None] * e[:, None, :]).reshape(n, nb * nb)]
    sums = band_sum(problem, jnp.concatenate(parts, axis=1))  # (W, nb + nb·q + nb²)
    g_band = sums[:, :nb]
    h_band_c = sums[:, nb: nb + nb * q].reshape(W, nb, q)
    h_band_band = sums[:, nb + nb * q:].reshape(W, nb, nb)
    g_c, h_cc = c.T @ r, c.T @ c

    def block(ki, kj):
        if ki in banded:
            i = banded.index(ki)
            return jnp.diag(h_band_band[:, i, banded.index(kj)]) if kj in banded else h_band_c[:, i, where[kj]]
        return h_band_c[:, banded.index(kj), where[ki]].T if kj in banded else h_cc[where[ki], where[kj]]

    grad = jnp.concatenate([g_band[:, banded.index(k)] if k in banded else g_c[where[k]] for k in names])
    return grad, jnp.concatenate([jnp.concatenate([block(ki, kj) for kj in names], axis=1) for ki in names], axis=0)


def _dir_sum(problem: Problem, x):
    """Σ over the samples of each direction pair: (D,) from a layout-shaped array."""
    if problem.spec.grid:
        return jnp.sum(x, axis=1)
    if problem.pair is None:  # each sample its own pair
        return x
    return jax.ops.segment_sum(x, problem.pair, num_segments=problem.geom.cos_vh.shape[0])


def _blocks(problem: Problem, r, cols: dict, names: list[str]):
    """(Jᵀr, JᵀJ) block by block from the factored columns ``cols`` and the residual ``r`` (layout shape)."""
    W = problem.fixed_bands

    def dense(kind, col, rhs):
        """Σ_i col_i(·) · rhs_i for a layout-shaped ``rhs``: shape (size,)."""
        if kind == "shape":
            a, js = col
            return js.T @ _dir_sum(problem, a * rhs)
        if kind == "scalar":
            return jnp.sum(col * rhs)[None]
        return band_sum(problem, col * rhs)

    def block(ki, ci, kj, cj):
        if ki == "band" and kj == "band":
            return jnp.diag(band_sum(problem, ci * cj))
        if ki == "band":
            return block(kj, cj, ki, ci).T
        if ki == "scalar":
            if kj == "scalar":
                return jnp.sum(ci * cj)[None, None]
            if kj == "band":
                return band_sum(problem, ci * cj)[None, :]
            return block(kj, cj, ki, ci).T
        a, js = ci
        if kj == "shape":
            b, js2 = cj
            return js.T @ (_dir_sum(problem, a * b)[:, None] * js2)
        if kj == "scalar":
            return (js.T @ _dir_sum(problem, a * cj))[:, None]
        # shape × band: Σ over samples of band b of a_i e_i J_S[d_i]
        if problem.spec.grid:
            return js.T @ (a * cj)
        return jax.ops.segment_sum((a * cj)[:, None] * at_samples(problem, js), problem.band, num_segments=W).T  # type: ignore[arg-type]  # set when not grid

    grad = jnp.concatenate([dense(cols[k][0], cols[k][1], r) for k in names]) if names else jnp.zeros((0,), r.dtype)
    rows = [jnp.concatenate([block(*cols[ki], *cols[kj]) for kj in names], axis=1) for ki in names]
    return grad, (jnp.concatenate(rows, axis=0) if names else jnp.zeros((0, 0), r.dtype))


def _spread(problem: Problem, kind: str, col):
    """A parameter's Jacobian columns in the problem's layout + (size,): a shape parameter's J_S
    at each sample's direction, a band parameter's column one per band (zero off its band)."""
    if kind == "scalar":
        return col[..., None]
    if kind == "band":
        one_hot = jnp.eye(problem.fixed_bands, dtype=col.dtype)
        return col[..., None] * (one_hot[None] if problem.spec.grid else one_hot[problem.band])
    a, js = col
    return a[..., None] * (js[:, None, :] if problem.spec.grid else at_samples(problem, js))


@jax.custom_jvp
def _residual(u: dict, y, problem: Problem):
    return loss_residuals(problem, model_values(problem, u), y)


@_residual.defjvp
def _residual_jvp(primals, tangents):
    u, y, problem = primals
    tu, ty, _ = tangents  # the problem (geometry, weights) is data: no derivative through it
    res, values, cols = _columns(problem, u, y)
    dres: Any = 0
    for name, (kind, col) in cols.items():
        t = tu[name]
        if kind == "shape":
            a, js = col
            ds = js @ t.reshape(-1)
            dres = dres + a * (ds[:, None] if problem.spec.grid else at_samples(problem, ds))
        elif kind == "scalar":
            dres = dres + col * t
        else:
            dres = dres + col * (t if problem.spec.grid else t[problem.band])
    dres = jnp.reshape(dres, (-1,)) if cols else jnp.zeros_like(res)
    # Data tangent: ∂r/∂y.
    _, dres_dy = jax.jvp(lambda yy: loss_residuals(problem, values, yy), (y,), (ty,))
    return res, dres + dres_dy


def residual(u: dict, args):
    """optimistix residual function: ``args = (y, problem)``; returns the flat residual vector."""
    y, problem = args
    return _residual(u, y, problem)
