"""3 x 3 algebra (dejax.tensor): values against numpy, and the closed-form derivative rules
of det3 and inv3 (custom_jvp) against jax's LAPACK-based det / inv and central differences,
in forward and reverse mode and to second order (the material tangent differentiates
det3 and inv3 twice)."""
import jax
import jax.numpy as jnp
import numpy as np
import pytest

from dejax.tensor import adj3, det3, gram3, inv3, mm3

RNG = np.random.default_rng(14)
# well-conditioned, with negative entries and det far from 1 (a 3 x 3 deformation gradient)
A = np.eye(3) * 1.3 + 0.4 * RNG.standard_normal((3, 3))
B = RNG.standard_normal((3, 3))
DA = RNG.standard_normal((3, 3))


def test_products_and_adjugate_against_numpy():
    np.testing.assert_allclose(mm3(A, B), A @ B, rtol=1e-14, atol=1e-14)
    np.testing.assert_allclose(gram3(A), A.T @ A, rtol=1e-14, atol=1e-14)
    d = np.linalg.det(A)
    assert abs(d) > 0.5
    np.testing.assert_allclose(A @ np.asarray(adj3(A)), d * np.eye(3), atol=1e-14)
    np.testing.assert_allclose(adj3(A), d * np.linalg.inv(A), rtol=1e-13)
    assert float(det3(A)) == pytest.approx(d, rel=1e-14)
    np.testing.assert_allclose(inv3(A), np.linalg.inv(A), rtol=1e-13)
    # the cofactor formula has no pivoting: an exact zero on the diagonal is fine
    P = np.array([[0.0, 2.0, 0.0], [3.0, 0.0, 0.0], [0.0, 0.0, 5.0]])
    assert float(det3(P)) == -30.0
    np.testing.assert_allclose(inv3(P), np.linalg.inv(P), rtol=1e-15)


def test_batched_over_points():
    As = np.eye(3) + 0.3 * RNG.standard_normal((7, 3, 3))
    np.testing.assert_allclose(jax.vmap(det3)(As), np.linalg.det(As), rtol=1e-13)
    np.testing.assert_allclose(jax.vmap(inv3)(As), np.linalg.inv(As), rtol=1e-12)
    np.testing.assert_allclose(jax.vmap(mm3)(As, As), As @ As, rtol=1e-14, atol=1e-14)


@pytest.mark.parametrize("f, ref", [(det3, jnp.linalg.det), (inv3, jnp.linalg.inv)], ids=["det3", "inv3"])
def test_derivatives_match_lapack_forms_and_central_differences(f, ref):
    jit = jax.jit  # each derivative one compiled program, not one per operation
    J = np.asarray(jit(jax.jacfwd(f))(jnp.asarray(A)))
    np.testing.assert_allclose(J, jit(jax.jacfwd(ref))(jnp.asarray(A)), rtol=1e-12, atol=1e-13)
    np.testing.assert_allclose(jit(jax.jacrev(f))(jnp.asarray(A)), J, rtol=1e-13, atol=1e-14)  # transposed rule
    h = 1e-6
    fd = (np.asarray(jit(f)(A + h * DA)) - np.asarray(jit(f)(A - h * DA))) / (2 * h)
    _, jvp = jit(lambda a, da: jax.jvp(f, (a,), (da,)))(jnp.asarray(A), jnp.asarray(DA))
    np.testing.assert_allclose(jvp, fd, rtol=1e-8, atol=1e-9)
    # second order: forward over forward and forward over reverse
    H = np.asarray(jit(jax.jacfwd(jax.jacfwd(f)))(jnp.asarray(A)))
    np.testing.assert_allclose(H, jit(jax.jacfwd(jax.jacfwd(ref)))(jnp.asarray(A)), rtol=1e-11, atol=1e-12)
    np.testing.assert_allclose(jit(jax.jacfwd(jax.jacrev(f)))(jnp.asarray(A)), H, rtol=1e-12, atol=1e-13)


def test_closed_forms_of_the_derivatives():
    """d det A = tr(adj(A) dA) = det(A) tr(A^-1 dA); d A^-1 = -A^-1 dA A^-1."""
    Ai = np.linalg.inv(A)
    _, d_det = jax.jvp(det3, (jnp.asarray(A),), (jnp.asarray(DA),))
    assert float(d_det) == pytest.approx(np.linalg.det(A) * np.trace(Ai @ DA), rel=1e-13)
    _, d_inv = jax.jvp(inv3, (jnp.asarray(A),), (jnp.asarray(DA),))
    np.testing.assert_allclose(d_inv, -Ai @ DA @ Ai, rtol=1e-12, atol=1e-13)
