"""Levenberg–Marquardt in optimistix on the structured normal equations.

optimistix's :class:`optimistix.LevenbergMarquardt` linearises the residual and materialises the
(N + P) × P damped Jacobian every step. For a BRDF fit N is 10⁵–10⁶ samples and P a few dozen
parameters, and JᵀJ (P × P) can be formed directly from the Jacobian's structure
(:func:`ctfit._problem.normal_equations`) without ever building J.

:class:`StructuredLevenbergMarquardt` is an :class:`optimistix.AbstractQuasiNewton` whose
"Hessian approximation" is that Gauss–Newton matrix JᵀJ, recomputed at every accepted point,
combined with optimistix's :class:`~optimistix.DampedNewtonDescent` (solving (JᵀJ + λI) δ = −Jᵀr)
and :class:`~optimistix.ClassicalTrustRegion` (λ from the ratio of actual to predicted
reduction): the Levenberg–Marquardt method, driven by ``optimistix.minimise`` on the cost
½‖r‖², with optimistix's termination tests, adjoints and result codes.
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

__all__ = ["StructuredLevenbergMarquardt"]


class _TrustRegion(optx.ClassicalTrustRegion):
    """optimistix's classical trust region with its step size in the iterate's dtype.

    The parent starts the step size as a default-dtype array, which is float64 whenever x64 is
    enabled and would promote a float32 solve to float64 halfway through.
    """

    def init(self, y, f_info_struct):
        state = super().init(y, f_info_struct)
        dtype = jax.tree.leaves(y)[0].dtype
        return jax.tree.map(lambda a: a.astype(dtype) if jnp.issubdtype(a.dtype, jnp.floating) else a, state)


class StructuredLevenbergMarquardt(optx.AbstractQuasiNewton):
    """Levenberg–Marquardt with a user-supplied Gauss–Newton matrix.

    ``gauss_newton(y, data) -> JᵀJ`` (a (P, P) array for the flat parameter vector ``y``; ``data``
    is the pytree held in the field of that name) is called at the starting point and at every
    accepted point. The objective given to ``optimistix.minimise`` must be ½‖r(y)‖² for the same
    residual r.
    """

    rtol: float
    atol: float
    data: Any
    gauss_newton: Callable[[Array, Any], Array] = eqx.field(static=True)
    norm: Callable = optx.max_norm
    use_inverse: bool = eqx.field(static=True, default=False)
    descent: optx.DampedNewtonDescent = optx.DampedNewtonDescent(linear_solver=lx.Cholesky())
    search: optx.ClassicalTrustRegion = _TrustRegion()
    verbose: Callable = eqx.field(static=True, default=lambda **kw: None)

    def _hessian(self, y):
        h = self.gauss_newton(y, self.data)
        return lx.MatrixLinearOperator(h, lx.positive_semidefinite_tag)

    def init_hessian(self, y, f, grad):
        return optx.FunctionInfo.EvalGradHessian(f, grad, self._hessian(y)), None

    def update_hessian(self, y, y_eval, f_info, f_eval_info, hessian_update_state):
        hess = self._hessian(y_eval)
        return optx.FunctionInfo.EvalGradHessian(f_eval_info.f, f_eval_info.grad, hess), None

