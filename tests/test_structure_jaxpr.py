"""The structure is static and unused terms are left out, proven on the traced program (jaxpr).

A Structure decides which terms exist: a d = 0 metal traces no diffuse operations and has no s
or R_d leaf; an s = 0 material traces no exp, erf or sqrt at all; the V-cavity traces no erf.
The parameters the model reads are exactly the Params leaves, and new values never retrace.
"""

import equinox as eqx
import jax
import jax.extend as jex
import jax.numpy as jnp
import numpy as np
import pytest
from helpers import PARAM_FIELDS, STRUCTURES, directions, make_params, structure_id

import ctfit
from ctfit import Params, Structure

DIFFUSE_ONLY = [Structure(lobes=0, fresnel=fr, diffuse=d) for fr in ("f0", "n", "conductor") for d in ("F0/pi", "spectrum", "constant")]

L = directions([10.0, 40.0, 70.0], [0.0, 0.0, 0.0])
V = directions([20.0, 45.0, 60.0], [180.0, 170.0, 90.0])
GEOM = ctfit.geometry(jnp.asarray(L), jnp.asarray(V))


def _subjaxprs(eqn):
    for v in eqn.params.values():
        for x in v if isinstance(v, (tuple, list)) else (v,):
            if isinstance(x, jex.core.ClosedJaxpr):
                yield x.jaxpr
            elif isinstance(x, jex.core.Jaxpr):
                yield x


def _eqns(jaxpr):
    """Every equation, recursively through nested jaxprs (pjit, custom_jvp, ...)."""
    for eqn in jaxpr.eqns:
        yield eqn
        for sub in _subjaxprs(eqn):
            yield from _eqns(sub)


def _trace(st, params):
    return jax.make_jaxpr(lambda p, g: ctfit.brdf(st, p, g))(params, GEOM)


def _primitives(closed):
    return {e.primitive.name for e in _eqns(closed.jaxpr)}


def _n_eqns(closed):
    return sum(1 for _ in _eqns(closed.jaxpr))


def _leaf_names(params):
    return {f for f in PARAM_FIELDS if getattr(params, f) is not None}


def _expected_leaves(st):
    names = set()
    if st.has_s:
        names.add("s")
    if st.lobes:
        names |= {"m", "w"}
    if st.needs_fresnel_params:
        names |= {"f0": {"f0"}, "n": {"n"}, "conductor": {"n", "k"}}[st.fresnel]
    if st.diffuse in ("spectrum", "constant"):
        names.add("rd")
    return names


def test_metal_without_diffuse_part_traces_no_diffuse_operations():
    metal = Structure(lobes=2, diffuse=None)
    plastic = Structure(lobes=2, diffuse="spectrum")
    pm, pp = make_params(metal), make_params(plastic)
    assert "s" not in _leaf_names(pm) and "rd" not in _leaf_names(pm)
    assert {"s", "rd"} <= _leaf_names(pp)
    jm, jp = _trace(metal, pm), _trace(plastic, pp)
    assert _n_eqns(jm) < _n_eqns(jp)
    # The inputs of the traced program are exactly the leaves: m, w, f0 (+ s, rd) and 8 geometry fields.
    assert len(jm.jaxpr.invars) == len(jax.tree.leaves(pm)) + len(jax.tree.leaves(GEOM)) == 3 + 8
    assert len(jp.jaxpr.invars) == 5 + 8


def test_diffuse_only_material_traces_no_transcendental_at_all():
    """s = 0: no D, G or F — not a single exp, erf, sqrt, sin, atan or log."""
    st = Structure(lobes=0, diffuse="spectrum")
    p = make_params(st)
    assert _leaf_names(p) == {"rd"}
    prims = _primitives(_trace(st, p))
    assert not prims & {"exp", "exp2", "erf", "erfc", "sqrt", "rsqrt", "log", "sin", "cos", "atan", "atan2", "pow", "div"}, prims
    assert _n_eqns(_trace(st, p)) < 10


@pytest.mark.parametrize("distribution", ["beckmann", "gaussian"])
def test_v_cavity_traces_no_erf_and_smith_does(distribution):
    vc = Structure(lobes=1, distribution=distribution, geometry="v-cavity")
    sm = Structure(lobes=1, distribution=distribution, geometry="smith")
    assert "erf" not in _primitives(_trace(vc, make_params(vc)))
    assert "erf" in _primitives(_trace(sm, make_params(sm)))


def test_beckmann_traces_no_arctangent_and_gaussian_does():
    b = Structure(lobes=1)
    g = Structure(lobes=1, distribution="gaussian")
    assert not _primitives(_trace(b, make_params(b))) & {"atan", "atan2", "sin"}
    assert _primitives(_trace(g, make_params(g))) & {"atan", "atan2"}


def test_lobes_add_work_linearly():
    n1, n2, n3, n4 = (_n_eqns(_trace(Structure(lobes=k), make_params(Structure(lobes=k)))) for k in (1, 2, 3, 4))
    assert n1 < n2 < n3 < n4
    assert n4 - n3 == n3 - n2  # each further lobe: the same D̂ evaluation and one add


@pytest.mark.parametrize("st", STRUCTURES + DIFFUSE_ONLY, ids=structure_id)
def test_params_leaves_are_exactly_the_structures_parameters(st):
    """Every leaf the structure has is read by the model, and nothing else is an input."""
    p = make_params(st)
    assert _leaf_names(p) == _expected_leaves(st)
    closed = _trace(st, p)
    n_param = len(jax.tree.leaves(p))
    used = {v for e in closed.jaxpr.eqns for v in e.invars if isinstance(v, jex.core.Var)} | {
        v for v in closed.jaxpr.outvars if isinstance(v, jex.core.Var)
    }
    unused = [i for i, v in enumerate(closed.jaxpr.invars[:n_param]) if v not in used]
    assert not unused, f"parameter leaves {unused} are not read by {structure_id(st)}"


def test_extra_leaves_are_ignored_not_traced_into_the_result():
    """A Params with fields the structure does not use: those inputs are dead in the program."""
    st = Structure(lobes=1, diffuse=None)
    p = make_params(st)
    extra = Params(m=p.m, w=p.w, f0=p.f0, s=jnp.asarray(0.5), rd=jnp.asarray([0.1, 0.2, 0.3]))
    closed = _trace(st, extra)
    leaves, _ = jax.tree.flatten(extra)
    used = {v for e in closed.jaxpr.eqns for v in e.invars if isinstance(v, jex.core.Var)}
    n_used = sum(v in used for v in closed.jaxpr.invars[: len(leaves)])
    assert n_used == 3


def test_no_retrace_for_new_values_and_equal_structures():
    @eqx.filter_jit
    @eqx.debug.assert_max_traces(max_traces=1)
    def f(st, p, g):
        return ctfit.brdf(st, p, g)

    st = Structure(lobes=2, geometry="smith", fresnel="conductor", diffuse="spectrum")
    rng = np.random.default_rng(0)
    outs = []
    for _ in range(4):
        p = make_params(Structure(lobes=2, geometry="smith", fresnel="conductor", diffuse="spectrum"), m=tuple(rng.uniform(0.05, 0.5, 2)), s=rng.uniform(),
                        rd=tuple(rng.uniform(0, 0.3, 3)))
        outs.append(np.asarray(f(st, p, GEOM)))
    assert not np.allclose(outs[0], outs[1])  # the values did change
    # Another structure is another program (one more trace of the same function would raise).
    with pytest.raises(RuntimeError, match="traced"):
        f(Structure(lobes=1), make_params(Structure(lobes=1)), GEOM)


@pytest.mark.parametrize("dtype", [jnp.float32, jnp.float64])
def test_dtype_follows_the_inputs(dtype):
    """float32 in, float32 throughout (even with x64 enabled): no equation produces float64."""
    st = Structure(lobes=2, geometry="smith", fresnel="conductor", diffuse="spectrum", distribution="gaussian")
    g = ctfit.geometry(jnp.asarray(L, dtype), jnp.asarray(V, dtype))
    closed = jax.make_jaxpr(lambda p, g: ctfit.brdf(st, p, g))(make_params(st, dtype), g)
    assert closed.out_avals[0].dtype == dtype
    wide = {e.primitive.name for e in _eqns(closed.jaxpr) for o in e.outvars if getattr(o.aval, "dtype", None) == jnp.float64}
    assert not wide if dtype == jnp.float32 else wide
