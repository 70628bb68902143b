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
