"""Material parameters by name (dejax.parameters): the round trips between a Material and dicts."""
import jax
import jax.numpy as jnp
import numpy as np
import pytest

from dejax import parameters as P
from dejax import scenarios

TWO_UNITS = dict(mu_inf=20e3, K_inf=2e7, Jm_inf=60.0, eps=4.7e-11, rho=960.0,
                 mu_1=30e3, K_1=3e7, Jm_1=50.0, eta_1=3e3, mu_2=10e3, K_2=1e7, Jm_2=50.0, eta_2=2e4)


def test_names_flat_and_from_flat_round_trip():
    assert P.names(0) == ["mu_inf", "K_inf", "Jm_inf", "eps", "rho"]
    assert P.names(2) == list(TWO_UNITS)
    mat = P.from_flat(TWO_UNITS, 2)
    assert mat.n_units == 2 and float(mat.eta[1]) == 2e4 and float(mat.K[0]) == 3e7
    assert P.flat(mat) == TWO_UNITS
    assert P.flat(mat, damping=3.0) == dict(TWO_UNITS, c_d=3.0)
    assert P.from_flat({k: TWO_UNITS[k] for k in P.names(0)}, 0).n_units == 0


def test_material_kwargs_keep_floats_and_stack_traced_values():
    kw = P.material_kwargs(TWO_UNITS, 2)
    assert kw["mu"] == (30e3, 10e3) and kw["mu_inf"] == 20e3
    kw = P.material_kwargs(dict(TWO_UNITS, eta_2=jnp.asarray(5.0)), 2)
    np.testing.assert_allclose(kw["eta"], [3e3, 5.0])
    # differentiable through the construction
    g = jax.grad(lambda e: P.from_flat(dict(TWO_UNITS, eta_1=e), 2).eta.sum())(1.0)
    assert float(g) == 1.0


def test_replace_named_leaves():
    m = scenarios.block_material()
    m2 = P.replace(m, {"mu_inf": 1.0, "eta_1": 2.0, "Jm_1": 3.0, "c_d": 9.0})
    assert float(m2.mu_inf) == 1.0 and float(m2.eta[0]) == 2.0 and float(m2.Jm[0]) == 3.0
    assert float(m2.K_inf) == float(m.K_inf)
    assert jax.tree_util.tree_structure(m2) == jax.tree_util.tree_structure(m)
    with pytest.raises(KeyError, match="1 viscous unit"):
        P.replace(m, {"eta_2": 1.0})
    with pytest.raises(KeyError, match="unknown parameter"):
        P.replace(m, {"nope": 1.0})


def test_fields_are_the_results_file_attributes():
    m = scenarios.rolled_material("II")
    f = P.fields(m)
    assert list(f) == ["mu_inf", "K_inf", "Jm_inf", "eps", "rho", "mu", "K", "Jm", "eta"]
    np.testing.assert_allclose(f["eta"], [300.0, 200.0])
    np.testing.assert_allclose(scenarios.rolled(m, shape=(1, 4, 1)).params["mu"], f["mu"])


def test_units():
    assert P.unit("eta_2") == "Pa s" and P.unit("c_d") == "1/s" and P.unit("Jm_1") == "1"
    assert P.unit("mu_inf") == "Pa" and P.unit("eps") == "F/m"


def test_vector_of_named_values_round_trips_in_the_order_of_the_names():
    names = ("eta_2", "h", "mu_inf")  # any names, in the caller's order (a sensitivity's geometry too)
    params = dict(TWO_UNITS, h=2e-3)
    p = P.to_vector(params, names)
    assert p.dtype == jnp.float64 and p.shape == (3,)
    np.testing.assert_array_equal(p, [2e4, 2e-3, 20e3])
    back = P.from_vector(p * 2, names, params)
    assert float(back["eta_2"]) == 4e4 and float(back["h"]) == 4e-3 and float(back["mu_inf"]) == 40e3
    assert back["K_inf"] == params["K_inf"] and params["eta_2"] == 2e4  # base unchanged
    assert P.to_vector(params, ()).shape == (0,) and P.from_vector(jnp.zeros(0), (), params) == params
    with pytest.raises(KeyError, match="'nope', 'c_d'"):
        P.to_vector(params, ("mu_1", "nope", "c_d"))
    with pytest.raises(ValueError, match="for 2 names"):
        P.from_vector(jnp.ones(3), ("mu_1", "eta_1"))
    # differentiable end to end: vector -> dict -> Material
    f = lambda v: P.from_flat(P.from_vector(v, ("mu_1", "eta_2"), TWO_UNITS), 2).eta.sum() * v[0]  # noqa: E731
    np.testing.assert_allclose(jax.grad(f)(jnp.asarray([3.0, 5.0])), [3e3 + 5.0, 3.0])
