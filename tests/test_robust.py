"""dejax.robust: the solver robustness matrix of ``dejax bench --cases robust``.

The full matrix takes about 20 minutes (run it with ``dejax bench --cases robust``); here
its case list, the selection and one one-element case run end to end. What a row reports
is checked against the closed-form count of steps and the outcome codes of
``dejax.integrate``."""
import numpy as np

from dejax import integrate as it
from dejax import robust


def _names(cases):
    return [name for name, _ in cases]


def test_the_matrix_lists_each_case_once():
    uni, block, tube = _names(robust.uniaxial_cases()), _names(robust.block_cases()), _names(robust.tube_cases())
    tors = _names(robust.torsional_cases())
    # uniaxial: 2 stretches x 2 materials x (5 mixed + 4 penalty bulk moduli) x 3 increments
    assert len(uni) == 2 * 2 * 9 * 3 and len(block) == 2 * 3 * 2 and len(tube) == 3 * 2 and len(tors) == 2 * 2
    everything = uni + block + tube + tors
    assert len(set(everything)) == len(everything) == 130
    assert not any("penalty" in n and "K/mu inf" in n for n in uni)  # K = inf needs the mixed form


def test_a_selected_case_runs_and_its_row_says_how():
    """One element, stretch 1 -> 3 in increments of 0.2 (10 steps), K = 1e4 mu, mixed form."""
    rows = robust.run(select=("uniaxial lam 3 K/mu 10000 inc 0.2 hyper mixed",))
    assert len(rows) == 1
    r = rows[0]
    assert r["case"] == "uniaxial lam 3 K/mu 10000 inc 0.2 hyper mixed" and r["steps"] == 10
    assert r["passed"] and r["status"] == it.Status.OK.name and r["cutbacks"] == 0
    assert 1 <= r["newton_median"] <= r["newton_max"] <= 6 and r["factorizations"] >= 10
    table = robust.format_table(rows + [dict(r, case="a failed case", passed=False, status="NEWTON_FAILED",
                                             fail_time=12.5)])
    assert "1 of 2 cases pass" in table
    assert "FAIL NEWTON_FAILED t=12.5" in table
    assert robust.run(select=("no such case",)) == []
    assert np.isfinite(r["wall_s"]) and r["wall_s"] > 0
