"""fitting.selection: information criteria against their formulas and against a model
choice with a known answer (the degree of a noisy polynomial), the per-point least-squares
weighting through fitting.fit, unit sorting, multi-start agreement (a two-exponential
model whose units can swap), per-curve errors, the text table."""
import math
import types

import jax.numpy as jnp
import numpy as np
import pytest

from fitting import selection as S
from fitting.fit import Target, fit


def test_information_criteria_formulas():
    ic = S.information_criteria(2.0, 10, 3)
    assert ic["bic"] == pytest.approx(10 * math.log(0.2) + 3 * math.log(10), rel=1e-14)
    assert ic["aic"] == pytest.approx(10 * math.log(0.2) + 6, rel=1e-14)
    assert (ic["rss"], ic["n"], ic["k"]) == (2.0, 10, 3)
    with pytest.raises(ValueError):
        S.information_criteria(0.0, 10, 3)
    with pytest.raises(ValueError):
        S.information_criteria(1.0, 0, 1)


def test_bic_picks_the_degree_of_a_noisy_polynomial():
    """Least-squares polynomials of degree 0..6 to a quadratic with noise: the BIC minimum is
    the true degree (a higher degree lowers the RSS, the penalty outweighs it)."""
    rng = np.random.default_rng(0)
    x = np.linspace(-1, 1, 200)
    y = 1.0 - 2.0 * x + 3.0 * x ** 2 + 0.1 * rng.standard_normal(x.size)
    bic = []
    for deg in range(7):
        c = np.polyfit(x, y, deg)
        r = np.polyval(c, x) - y
        bic.append(S.information_criteria(float(r @ r), x.size, deg + 1)["bic"])
    assert int(np.argmin(bic)) == 2
    assert bic[1] > bic[2] + 100  # the quadratic term is plainly needed


def decay(params, data):
    """A toy forward with the material's unit names: sum_i mu_i exp(-t / tau_i), tau_i =
    eta_i / (2 mu_i); non-finite where mu_1 > 500 (a 'failed simulation')."""
    t = data["t"]
    y = params["mu_1"] * jnp.exp(-t * 2 * params["mu_1"] / params["eta_1"])
    y = y + params["mu_2"] * jnp.exp(-t * 2 * params["mu_2"] / params["eta_2"])
    return jnp.where(params["mu_1"] > 500.0, jnp.nan, y)


TRUE = dict(mu_1=100.0, eta_1=200.0, mu_2=50.0, eta_2=1000.0)  # tau 1 s and 10 s
FREE = ["mu_1", "eta_1", "mu_2", "eta_2"]
BOUNDS = {"mu_1": (1.0, 1e3), "eta_1": (1.0, 1e5), "mu_2": (1.0, 1e3), "eta_2": (1.0, 1e5)}


def _targets(noise=0.5):
    rng = np.random.default_rng(1)
    out = []
    for name, t in (("short", np.linspace(0, 5, 30)), ("long", np.linspace(0, 40, 80))):
        y = np.asarray(decay(TRUE, {"t": jnp.asarray(t)})) + noise * rng.standard_normal(t.size)
        out.append(Target(name, y, {"t": jnp.asarray(t)}))
    return out


def test_per_point_least_squares_through_fit():
    targets = S.per_point_least_squares(_targets(), noise=0.5)
    assert [t.weight for t in targets] == [30.0, 80.0] and all(t.scale == 0.5 for t in targets)
    res = fit(decay, dict(mu_1=150.0, eta_1=500.0, mu_2=30.0, eta_2=500.0), FREE, BOUNDS, targets, verbose=False,
              max_evals=60)
    r = np.concatenate([res.predictions[t.name] - t.y for t in targets])
    assert res.loss == pytest.approx(float(r @ r) / 0.25, rel=1e-8)  # sum of squares over the noise^2
    ic = S.fit_criteria(res)
    assert ic["n"] == 110 and ic["k"] == 4 and ic["rss"] == pytest.approx(float(r @ r), rel=1e-12)
    assert math.sqrt(ic["rss"] / ic["n"]) < 0.6  # down to the noise (0.5)
    with pytest.raises(ValueError):
        S.per_point_least_squares(targets, 0.0)


def test_sort_units_by_relaxation_time():
    p = dict(mu_inf=1.0, mu_1=10.0, K_1=1.0, Jm_1=5.0, eta_1=2000.0,   # tau 100 s
             mu_2=20.0, K_2=2.0, Jm_2=6.0, eta_2=40.0,                  # tau 1 s
             mu_3=30.0, K_3=3.0, Jm_3=7.0, eta_3=600.0)                 # tau 10 s
    assert S.relaxation_times(p) == {1: 100.0, 2: 1.0, 3: 10.0}
    q = S.sort_units(p)
    assert list(q) == list(p)
    assert S.relaxation_times(q) == {1: 1.0, 2: 10.0, 3: 100.0}
    assert (q["mu_1"], q["K_1"], q["Jm_1"], q["eta_1"]) == (20.0, 2.0, 6.0, 40.0)
    assert (q["mu_3"], q["K_3"], q["Jm_3"], q["eta_3"]) == (10.0, 1.0, 5.0, 2000.0)
    assert q["mu_inf"] == 1.0
    assert S.sort_units(q) == q
    order = S.unit_order(p)
    assert order == {2: 1, 3: 2, 1: 3}
    assert S.renumber(["mu_inf", "mu_1", "eta_2", "c_d"], order) == ["mu_inf", "mu_3", "eta_1", "c_d"]
    se = S.renumber({"mu_1": 0.1, "eta_3": 0.2}, order)
    assert se == {"mu_3": 0.1, "eta_2": 0.2} and list(se) == ["mu_3", "eta_2"]


def test_multistart_reaches_one_optimum_up_to_swapped_units():
    """Three starts, one with the units' roles swapped, one whose 'simulation' fails: the two
    that run reach the same loss and, once units are sorted, the same parameters."""
    targets = S.per_point_least_squares(_targets(), noise=0.5)
    starts = [dict(mu_1=150.0, eta_1=500.0, mu_2=30.0, eta_2=500.0),
              dict(mu_1=30.0, eta_1=1000.0, mu_2=150.0, eta_2=300.0),   # unit 1 slow, unit 2 fast
              dict(mu_1=600.0, eta_1=500.0, mu_2=30.0, eta_2=500.0)]    # non-finite at the start
    said = []
    out = S.multistart(lambda s: fit(decay, s, FREE, BOUNDS, targets, verbose=False, max_evals=80), starts,
                       say=said.append)
    assert [o.result is None for o in out] == [False, False, True]
    assert "not finite" in out[2].error and len(said) == 3 and all(o.seconds >= 0 for o in out)
    a = S.agreement(out)
    assert a["n"] == 3 and a["n_ok"] == 2 and a["losses"][2] is None
    assert sorted(a["same_loss"]) == [0, 1] and sorted(a["same_params"]) == [0, 1]
    assert all(v < 0.05 for v in a["spread"].values())
    raw = out[0].result.params, out[1].result.params  # unsorted they differ: the units swapped
    assert abs(math.log(raw[0]["mu_1"] / raw[1]["mu_1"])) > 0.5
    for k in FREE:  # the sorted optimum is the truth within the noise
        assert S.sort_units(out[a["best"]].result.params)[k] == pytest.approx(TRUE[k], rel=0.15)


def _fake(loss, **p):
    return types.SimpleNamespace(loss=loss, params=dict(mu_inf=1.0, **p), free=["mu_inf", "mu_1", "eta_1"])


def test_agreement_separates_optima():
    res = [_fake(10.0, mu_1=1.0, eta_1=2.0), _fake(10.05, mu_1=1.02, eta_1=2.0), _fake(10.05, mu_1=2.0, eta_1=2.0),
           _fake(30.0, mu_1=1.0, eta_1=2.0), None]
    a = S.agreement(res)
    assert a["best"] == 0 and a["n_ok"] == 4
    assert a["same_loss"] == [0, 1, 2]          # within 1 % of the best loss
    assert a["same_params"] == [0, 1, 3]        # within 0.05 in ln p (the worse loss is a flat direction)
    assert a["spread"]["mu_1"] == pytest.approx(math.log(2.0))
    assert S.agreement([None, None])["best"] is None


def test_curve_errors_and_table():
    t1 = Target("a", np.array([0.0, 2.0, 1.0]), None)
    t2 = Target("b", np.array([1.0, 4.0]), None)
    res = types.SimpleNamespace(targets=[t1], holdout=[t2],
                                predictions={"a": np.array([1.0, 2.0, 1.0]), "b": np.array([1.0, 5.0])})
    rows = S.curve_errors(res)
    assert [r["role"] for r in rows] == ["fit", "holdout"]
    assert rows[0]["rms"] == pytest.approx(math.sqrt(1 / 3)) and rows[0]["peak_error"] == 0.0
    assert rows[1]["rms"] == pytest.approx(math.sqrt(0.5)) and rows[1]["peak_error"] == 1.0
    assert rows[1]["rel_peak_error"] == pytest.approx(0.25)
    s = S.text_table(["curve", "rms"], [["a", 1.23456], ["bb", float("nan")], ["c", 7]])
    lines = s.splitlines()
    assert lines[0] == "curve    rms" and set(lines[1]) == {"-", " "}
    assert lines[2] == "    a  1.235" and lines[3].endswith("-") and lines[4].endswith("7")
    with pytest.raises(ValueError):
        S.text_table(["a", "b"], [[1]])
