"""fitting.sensitivity: forward-mode Jacobians (jax.jacfwd through mesh generation and
time stepping) of the tiny tube's x_P(t) and cycle features against central finite
differences of the same simulation (independent of the derivative rules).

Tiny tube (1, 4, 1), Model I, 100 Hz sine, 60 steps of 5e-4 s (3 cycles). Compiles
a forward and a jacfwd tube simulation (minutes on a loaded 2-core machine): slow."""
import numpy as np
import pytest

from fitting import sensitivity as S

NAMES = ("h", "L", "r", "mu_inf", "eta_1")


@pytest.mark.slow
def test_jacfwd_matches_central_differences():
    setup = S.Setup()
    params = S.default_params(setup)
    res = S.sensitivity(params, NAMES, setup, timing=False)
    fd = S.finite_differences(params, NAMES, setup, rel_step=1e-4)
    assert np.all(np.isfinite(res["values"]["x_P"]))
    assert np.max(np.abs(res["values"]["x_P"])) > 0
    for key in ("x_P", "x_max", "x_min", "mean", "loop_area", "k_c"):
        err = S.relative_error(res["jacobian"][key], fd[key])
        assert err < 1e-4, (key, err)
    # every parameter matters for x_P (the check is not vacuous)
    assert np.all(np.max(np.abs(res["jacobian"]["x_P"]), axis=0) > 0)


@pytest.mark.slow
def test_reverse_mode_agrees_with_forward_mode_at_fixed_field():
    """One reverse pass per output (w^T J through the transposed implicit step rule) against
    jacfwd, with phi_max = field * h (so d/dh also moves the voltage), and jacfwd against
    central differences there too."""
    setup = S.Setup(t_end=0.02, field=1.25e7)
    params = S.default_params(setup)
    names = ("h", "mu_1")
    res = S.sensitivity(params, names, setup, timing=False)
    chk = S.reverse_check(params, names, setup, jacobian=res["jacobian"])
    assert set(chk["rows"]) == set(res["jacobian"])
    for key, row in chk["rows"].items():
        # both modes solve the same linear systems: they differ by round-off amplified by the
        # tangent's conditioning (~1e9 on the tube), far below the 1e-4 asked of FD; a wrong
        # transposition would differ at O(1)
        assert row["rel_error"] < 1e-6, (key, row)
        assert np.max(np.abs(row["forward"])) > 0
    fd = S.finite_differences(params, names, setup, rel_step=1e-4)
    assert S.relative_error(res["jacobian"]["x_P"], fd["x_P"]) < 1e-4
    # the fixed field is in the derivative: d x_P/dh differs from the fixed-voltage one
    fixed = S.sensitivity(params, ("h",), S.Setup(t_end=0.02, phi_max=1.25e7 * 2e-3), timing=False)
    np.testing.assert_allclose(fixed["values"]["x_P"], res["values"]["x_P"], rtol=1e-10, atol=1e-15)
    assert abs(fixed["jacobian"]["x_P"][-1, 0] - res["jacobian"]["x_P"][-1, 0]) > 1e-3 * abs(res["jacobian"]["x_P"][-1, 0])


def test_unknown_parameter_is_rejected():
    with pytest.raises(KeyError):
        S.sensitivity(S.default_params(S.Setup()), ["thickness"], S.Setup())


def test_relative_error_detects_mismatch():
    J = np.array([[1.0, 2.0], [3.0, 4.0]])
    assert S.relative_error(J, J) == 0.0
    assert S.relative_error(J * (1 + 1e-3), J) > 5e-4


def test_sensitivity_verb_rejects_bad_arguments(capsys):
    import argparse

    from fitting import cli as fitting_cli

    ap = argparse.ArgumentParser(prog="dejax")
    fitting_cli.register_sensitivity(ap.add_subparsers(dest="command", required=True))
    for argv in (["sensitivity", "--params", "h,thickness"], ["sensitivity", "--mesh", "2x2"]):
        args = ap.parse_args(argv)
        assert args.func(args) == 2
    assert "error" in capsys.readouterr().err


def test_check_rows_judges_only_derivatives_that_are_not_tiny():
    """A column whose relative sensitivity is below 1e-3 is listed as not judged; a wrong
    derivative elsewhere is caught; the judged row is the largest relative sensitivity."""
    p = np.array([2e-3, 5e4])
    y = np.array([1.0, 2.0, 4.0])
    J = np.array([[10.0, 1e-12], [20.0, 2e-12], [40.0, 4e-12]])  # d/dp1: relative 4e-8 x 5e4 / 4: tiny
    F = J.copy()
    F[:, 1] *= 1.5  # the differences of a tiny column are round-off: not judged
    res = dict(names=["h", "mu_1"], p=p, values={"x": y}, jacobian={"x": J})
    (row,) = S.check_rows(res, {"x": F})
    assert row["tiny"] == ["mu_1"] and row["fd_error"] < 1e-15 and row["param"] == "h" and row["row"] == 2
    assert abs(row["rel_sens"] - 40.0 * 2e-3 / 4.0) < 1e-15
    F[2, 0] *= 1.01  # a wrong judged entry
    (row,) = S.check_rows(res, {"x": F})
    assert 0.009 < row["fd_error"] < 0.011
