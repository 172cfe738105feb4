"""Levenberg–Marquardt in optimistix on the structured normal equations.

optimistix's :class:`optimistix.LevenbergMarquardt` linearises the residual and materialises the
(N + P) × P damped Jacobian every step. For a BRDF fit N is 10⁵–10⁶ samples and P a few dozen
parameters, and JᵀJ (P × P) can be formed directly from the Jacobian's structure
(:func:`ctfit._fitting.jacobian.normal_equations`) without ever building J.

:class:`StructuredLevenbergMarquardt` is an :class:`optimistix.AbstractMinimiser` that steps as
optimistix's quasi-Newton solvers do, with that Gauss–Newton matrix JᵀJ as the "Hessian
approximation", recomputed at every accepted point, combined with optimistix's :class:`~optimistix.DampedNewtonDescent` (solving (JᵀJ + λI) δ = −Jᵀr)
and :class:`~optimistix.ClassicalTrustRegion` (λ from the ratio of actual to predicted
reduction): the Levenberg–Marquardt method, driven by ``optimistix.minimise`` on the cost
½‖r‖², with optimistix's termination tests, adjoints and result codes.

With bounds (``lower``/``upper``), the descent is :class:`ProjectedDampedNewtonDescent`: a
projected Levenberg–Marquardt step in the manner of Kanzow, Yamashita & Fukushima (2004,
J. Comput. Appl. Math. 172, 375–397) and of Bertsekas' projected Newton method (1982, SIAM J.
Control Optim. 20, 221–246). Variables on a bound whose gradient points out of the box are
held there (the active set), the damped Newton system is solved on the others, and the trial
point is projected onto the box. A parameter that belongs on its bound (s = 1, F0 = 0, a weight
0) reaches it in one step and stays, and convergence is judged on the free variables.
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Any

import equinox as eqx
import jax
import jax.numpy as jnp
import lineax as lx
import optimistix as optx
from jaxtyping import Array

from .stationarity import active_set, cost_scale, predicted_decrease, stationary_decrease

__all__ = ["StructuredLevenbergMarquardt", "ProjectedDampedNewtonDescent", "active_set", "predicted_decrease", "small_change"]


class _TrustRegion(optx.ClassicalTrustRegion):
    """optimistix's classical trust region with its step size in the iterate's dtype.

    The parent starts the step size as a default-dtype array, which is float64 whenever x64 is
    enabled and would promote a float32 solve to float64 halfway through.
    """

    def init(self, y, f_info_struct):
        state = super().init(y, f_info_struct)
        dtype = jax.tree.leaves(y)[0].dtype
        return jax.tree.map(lambda a: a.astype(dtype) if jnp.issubdtype(a.dtype, jnp.floating) else a, state)


def small_change(rtol: float, atol: float, norm: Callable, y, y_diff, f, f_diff):
    """optimistix's Cauchy test, the one its quasi-Newton solvers stop on: in ``norm``, the change
    of y below ``atol + rtol·|y|`` and the change of the cost below ``atol + rtol·|f|``."""
    y_small = norm(jnp.abs(y_diff) / (atol + rtol * jnp.abs(y))) < 1
    f_small = norm(jnp.abs(f_diff) / (atol + rtol * jnp.abs(f))) < 1
    return y_small & f_small


class _ProjectedState(eqx.Module):
    y: Array
    f_info: Any  # optx.FunctionInfo.EvalGradHessian: a class attribute, not usable as a type


class ProjectedDampedNewtonDescent(optx.AbstractDescent):
    """Damped Newton (Levenberg–Marquardt) steps that stay inside the box [lower, upper].

    ``step(s)`` with λ = 1/s: solve (H_FF + λI) δ_F = −g_F on the free variables F (those not
    in :func:`active_set`), δ = 0 on the active ones, then project: δ ← clip(y + δ) − y. The
    trust region's predicted reduction is computed from the projected δ, so the accept/reject
    logic of :class:`optimistix.ClassicalTrustRegion` stays exact. ``y`` is a flat vector.
    """

    lower: Array
    upper: Array

    def init(self, y, f_info_struct):
        return _ProjectedState(jnp.zeros_like(y), jax.tree.map(lambda s: jnp.zeros(s.shape, s.dtype), f_info_struct))

    def query(self, y, f_info, state):
        del state
        return _ProjectedState(y, f_info)

    def step(self, step_size, state):
        y, info = state.y, state.f_info
        g, h = info.grad, info.hessian.as_matrix()
        dtype = y.dtype
        tiny = step_size <= jnp.finfo(dtype).eps
        lam = jnp.where(tiny, jnp.finfo(dtype).max ** 0.5, 1 / jnp.where(tiny, 1, step_size))
        free = ~active_set(y, g, self.lower, self.upper)
        both = free[:, None] & free[None, :]
        scale = jnp.maximum(jnp.max(jnp.abs(jnp.diag(h))), jnp.finfo(dtype).tiny)
        a = jnp.where(both, h, 0) + jnp.diag(jnp.where(free, lam, scale))
        rhs = jnp.where(free, -g, 0)
        sol = lx.linear_solve(lx.MatrixLinearOperator(a, lx.positive_semidefinite_tag), rhs, lx.Cholesky(), throw=False)
        # Where rounding makes the damped system fail to factor (float32, JᵀJ singular along
        # directions the data does not determine), take the diagonally scaled gradient step
        # instead: a descent direction, and the trust region shrinks it as with any other step.
        solved = (sol.result == lx.RESULTS.successful) & jnp.all(jnp.isfinite(sol.value))
        fallback = rhs / jnp.where(free, jnp.maximum(jnp.diag(h), 0) + lam, 1)
        delta = jnp.where(free, jnp.where(solved, sol.value, fallback), 0)
        target = jnp.clip(y + delta, self.lower, self.upper)
        return target - y, optx.RESULTS.successful


class _LevenbergMarquardtState(eqx.Module):
    """The solver's state: the point it evaluates next, the trust region's and the descent's
    states, the last accepted point's cost, Jᵀr and JᵀJ (and aux), whether to stop, the result
    so far and the accepted steps (the fields of optimistix's quasi-Newton state it uses)."""

    first_step: Array
    y_eval: Array
    search_state: Any
    f_info: Any  # optx.FunctionInfo.EvalGradHessian: a class attribute, not usable as a type
    aux: Any
    descent_state: Any
    terminate: Array
    result: optx.RESULTS
    num_accepted_steps: Array


class StructuredLevenbergMarquardt(optx.AbstractMinimiser):
    """Levenberg–Marquardt with a user-supplied gradient and Gauss–Newton matrix.

    ``gauss_newton(y, data) -> (Jᵀr, JᵀJ)`` (for the flat parameter vector ``y``; ``data`` is
    the pytree held in the field of that name) is called once at every accepted point. The
    objective given to ``optimistix.minimise`` must be ½‖r(y)‖² for the same residual r; it is
    only *evaluated* (never differentiated), once per step. So a step costs one evaluation of
    the cost plus, when accepted, one of the normal equations — where optimistix's own
    Levenberg–Marquardt linearises the residual (a Jacobian-sized pass) on every step.

    An :class:`optimistix.AbstractMinimiser` of its own (its state :class:`_LevenbergMarquardtState`),
    built of optimistix's public parts: its step is that of optimistix's quasi-Newton solvers,
    with the cost evaluated, not linearised, and the Hessian approximation JᵀJ.
    """

    rtol: float
    atol: float
    data: Any  # type: ignore[misc]  # the parent's fields are abstract (eqx.AbstractVar), not defaults
    gauss_newton: Callable[[Array, Any], Array] = eqx.field(static=True)  # type: ignore[misc]  # (the same)
    gtol: float = 0.0
    stol: float = jnp.inf
    zero_cost: Any = 0.0
    """The cost of a model that is 0 everywhere (may be traced; 0: not known): the stopping tests
    take a cost below ε times it as that (rounding), as ``gauss_newton_decrease`` does."""
    norm: Callable = optx.max_norm
    descent: optx.AbstractDescent = optx.DampedNewtonDescent(linear_solver=lx.Cholesky())
    search: optx.ClassicalTrustRegion = _TrustRegion()

    def init(self, fn, y, args, options, f_struct, aux_struct, tags):
        # The Hessian approximation starts as zeros of its shape: the first step is always
        # accepted and forms the normal equations at the start (the trust region accepts a first step).
        hess = lx.MatrixLinearOperator(jnp.zeros((y.size, y.size), y.dtype), lx.positive_semidefinite_tag)
        f_info = optx.FunctionInfo.EvalGradHessian(jnp.zeros(f_struct.shape, f_struct.dtype), jnp.zeros_like(y), hess)
        f_info_struct = eqx.filter_eval_shape(lambda: f_info)
        return _LevenbergMarquardtState(
            first_step=jnp.array(True), y_eval=y, search_state=self.search.init(y, f_info_struct), f_info=f_info,
            aux=jax.tree.map(lambda a: jnp.zeros(a.shape, a.dtype), aux_struct), descent_state=self.descent.init(y, f_info_struct),
            terminate=jnp.array(False), num_accepted_steps=jnp.array(0),
            result=optx.RESULTS.successful,  # type: ignore[arg-type]  # equinox's Enumeration items are typed str
        )

    def terminate(self, fn, y, args, options, state, tags):
        return state.terminate, state.result

    def postprocess(self, fn, y, aux, args, options, state, tags, result):
        return y, aux, {}

    def step(self, fn, y, args, options, state, tags):
        """optimistix's quasi-Newton step (``AbstractQuasiNewton.step``) with the cost evaluated,
        not linearised, and the gradient and JᵀJ of an accepted point from ``gauss_newton``."""
        f_eval, aux_eval = fn(state.y_eval, args)
        step_size, accept, search_result, search_state = self.search.step(
            state.first_step, y, state.y_eval, state.f_info, optx.FunctionInfo.Eval(f_eval), state.search_state
        )

        def accepted(descent_state):
            grad, hess = self.gauss_newton(state.y_eval, self.data)
            f_eval_info = optx.FunctionInfo.EvalGradHessian(f_eval, grad, lx.MatrixLinearOperator(hess, lx.positive_semidefinite_tag))
            descent_state = self.descent.query(state.y_eval, f_eval_info, descent_state)
            terminate = self._terminate(y, state.y_eval, state.f_info.f, f_eval_info)
            terminate = jnp.where(state.first_step, jnp.array(False), terminate)  # never on the first step
            return state.y_eval, f_eval_info, aux_eval, descent_state, terminate

        def rejected(descent_state):
            return y, state.f_info, state.aux, descent_state, jnp.array(False)

        y, f_info, aux, descent_state, terminate = jax.lax.cond(accept, accepted, rejected, state.descent_state)
        y_descent, descent_result = self.descent.step(step_size, descent_state)
        result = optx.RESULTS.where(search_result == optx.RESULTS.successful, descent_result, search_result)
        prev_aux = jax.tree.map(lambda a, b: jnp.where(state.first_step, a, b), aux, state.aux)
        state = _LevenbergMarquardtState(
            first_step=jnp.array(False),
            y_eval=y + y_descent,
            search_state=search_state,
            f_info=f_info,
            aux=aux,
            descent_state=descent_state,
            terminate=terminate,
            result=result,
            num_accepted_steps=state.num_accepted_steps + jnp.where(accept, 1, 0),
        )
        return y, state, prev_aux

    def _terminate(self, y, y_eval, f, info):
        """Whether to stop at the accepted point ``y_eval`` (``info``: its cost, Jᵀr and JᵀJ;
        ``y``, ``f``: the point before it and its cost).

        optimistix's test (small change in y and in the cost, :func:`small_change`) —
        with ``gtol`` > 0 only where one more projected Gauss–Newton step promises less than
        ``stol`` relative decrease (steps that barely move can still be making progress: a
        parameter creeping along a bound, a cost set by differences of 1 − F0 ≈ 10⁻⁶) — or
        a point where that step promises less than ``gtol``: this ends the slow slides along
        directions the data does not determine (R_d growing as s → 1, keeping d·R_d fixed),
        where the iterate keeps moving but the cost does not change. Both promises are relative to
        the cost, or to ε times the zero model's (``zero_cost``) where that is larger: at an exact
        fit (noise-free data the model made) the cost is rounding, and so is every decrease
        promised from it, which ran such fits to the step limit (256 steps, 7.5 s for 122,000
        samples, where they end in a few)."""
        small = small_change(self.rtol, self.atol, self.norm, y_eval, y_eval - y, info.f, info.f - f)
        if isinstance(self.gtol, (int, float)) and self.gtol <= 0:  # a traced gtol is > 0
            return small
        lower = getattr(self.descent, "lower", None)
        upper = getattr(self.descent, "upper", None)
        jtj = info.hessian.as_matrix()
        dec = predicted_decrease(jtj, info.grad) if lower is None else stationary_decrease(y_eval, info.grad, jtj, lower, upper)
        scale = cost_scale(info.f, self.zero_cost)
        return (small & (dec <= self.stol * scale)) | (dec <= self.gtol * scale)

