"""Experiment files (TOML + CSV): loading, unit conversion and every validation error."""
import math
import textwrap
from pathlib import Path

import numpy as np
import pytest

import fitting  # noqa: F401
from fitting.data import Experiment, load_experiment
from fitting.schema import DataError, loading_voltage
from fitting.traces import Trace, load_trace_csv
from helpers import CSV, raises  # noqa: E402  (tests/helpers.py)

REPO = Path(__file__).resolve().parents[1]
EXAMPLE = REPO / "data" / "examples" / "tube_example.toml"


TOML = """\
[experiment]
name = "test-exp"
scenario = "rolled"

[geometry]
h = 2e-3
r = 2e-3
L = 8e-3
mesh = [2, 8, 1]

[material]
mu_inf = 81e3
K_inf = 3e9
Jm_inf = 15.0
eps = 3.4e-11
rho = 1500.0

[[material.units]]
mu = 80e3
K = 7.5e9
Jm = 5.0
eta = 400.0

[fit]
free = ["mu_1", "eta_1"]

[fit.bounds]
mu_1 = [1e3, 1e6]
eta_1 = [1.0, 1e4]

[solver]
dt = 1e-4
rho_inf = 0.8

[[traces]]
file = "run.csv"
role = "fit"
conditions = { freq = 30.0, phi_max = 4.5e3 }
columns = { time = "t_ms", displacement = "disp_mm", voltage = "U_kV" }
units = { time = "ms", displacement = "mm", voltage = "kV" }
"""


def write(tmp_path, toml=TOML, csv=CSV, name="exp.toml", csv_name="run.csv"):
    (tmp_path / csv_name).write_text(csv)
    p = tmp_path / name
    p.write_text(toml)
    return p


# ---------------------------------------------------------------------------
# valid files
# ---------------------------------------------------------------------------


def test_valid_experiment_loads_in_si(tmp_path):
    exp = load_experiment(write(tmp_path))
    assert isinstance(exp, Experiment)
    assert exp.name == "test-exp" and exp.scenario == "rolled"
    assert exp.geometry == {"h": 2e-3, "r": 2e-3, "L": 8e-3, "mesh": (2, 8, 1)}
    assert len(exp.traces) == 1
    tr = exp.traces[0]
    assert isinstance(tr, Trace)
    assert tr.role == "fit" and tr.name == "run" and tr.source == tmp_path / "run.csv"
    assert tr.conditions == {"freq": 30.0, "phi_max": 4.5e3}
    np.testing.assert_allclose(tr.time, [0.0, 1e-3, 2e-3, 3e-3], rtol=1e-15)  # ms -> s
    np.testing.assert_allclose(tr["displacement"], [0.0, 0.5e-3, 1.0e-3, 1.5e-3], rtol=1e-15)  # mm -> m
    np.testing.assert_allclose(tr["voltage"], [0.0, 1500.0, 3000.0, 4500.0], rtol=1e-15)  # kV -> V
    assert set(tr.channels) == {"displacement", "voltage"}  # 'note' column ignored, time separate
    assert tr.dt == pytest.approx(1e-3) and tr.frequency == 30.0
    assert exp.fit.free == ("mu_1", "eta_1")
    assert exp.fit.bounds == {"mu_1": (1e3, 1e6), "eta_1": (1.0, 1e4)}
    assert exp.solver == {"dt": 1e-4, "rho_inf": 0.8}
    params = exp.parameters()
    assert params["mu_1"] == 80e3 and params["eta_1"] == 400.0 and params["geometry.h"] == 2e-3
    kw = exp.material_kwargs({"eta_1": 500.0})
    assert kw["eta"] == (500.0,) and kw["mu"] == (80e3,) and kw["mu_inf"] == 81e3


def test_material_kwargs_build_a_dejax_material(tmp_path):
    import jax.numpy as jnp
    from dejax.material import Material

    exp = load_experiment(write(tmp_path))
    mat = Material(**exp.material_kwargs({"mu_1": jnp.asarray(2e4)}))
    assert mat.n_units == 1 and float(mat.mu[0]) == 2e4 and float(mat.eta[0]) == 400.0


def test_optional_mullins_keys_reach_the_material(tmp_path):
    from dejax.material import Material

    toml = TOML.replace("mu_inf = 81e3", "mu_inf = 81e3\nmullins_d = 0.3\nmullins_m = 2e3")
    exp = load_experiment(write(tmp_path, toml))
    mat = Material(**exp.material_kwargs())
    assert float(mat.mullins_d) == 0.3 and float(mat.mullins_m) == 2e3
    assert float(Material(**load_experiment(write(tmp_path)).material_kwargs()).mullins_d) == 0.0  # off
    with pytest.raises(DataError, match="mullins_d.*must be < 1"):
        load_experiment(write(tmp_path, TOML.replace("mu_inf = 81e3", "mu_inf = 81e3\nmullins_d = 1.0")))


def test_loading_table_and_voltage(tmp_path):
    csv = "time_s,displacement_m\n0,0\n0.01,1e-5\n0.02,2e-5\n"
    toml = TOML.replace('columns = { time = "t_ms", displacement = "disp_mm", voltage = "U_kV" }\n'
                        'units = { time = "ms", displacement = "mm", voltage = "kV" }\n',
                        'columns = { time = "time_s", displacement = "displacement_m" }\n'
                        'loading = { kind = "sine", phi_max = 4.5e3, freq = 30.0 }\n')
    exp = load_experiment(write(tmp_path, toml, csv))
    tr = exp.traces[0]
    t = np.array([0.0, 0.01, 0.02])
    # paper Eq. 42, written out independently
    expected = 4.5e3 / 2 * (1 + np.sin(2 * np.pi * 30.0 * t + 1.5 * np.pi))
    np.testing.assert_allclose(np.asarray(tr.voltage()), expected, atol=1e-9)
    ramp = loading_voltage({"kind": "ramp_hold", "phi_max": 8e3, "t_ramp": 1.0}, np.array([0.0, 0.5, 1.0, 2.0]))
    np.testing.assert_allclose(np.asarray(ramp), [0.0, 4e3, 8e3, 8e3], atol=1e-9)
    pw = loading_voltage({"kind": "piecewise", "times": [0.0, 1.0], "values": [0.0, 10.0]}, np.array([0.5, 2.0]))
    np.testing.assert_allclose(np.asarray(pw), [5.0, 10.0])


def test_shipped_example_loads():
    exp = load_experiment(EXAMPLE)
    assert exp.scenario == "rolled" and exp.n_units == 1
    assert [t.role for t in exp.traces] == ["fit", "holdout"]
    fit, hold = exp.fit_traces[0], exp.holdout_traces[0]
    assert fit.frequency == 30.0 and hold.frequency == 10.0
    # whole cycles, uniformly sampled, displacements of order 0.1 mm (in m)
    assert fit.time[-1] == pytest.approx(5 / 30.0) and hold.time[-1] == pytest.approx(0.3)
    assert 1e-5 < fit["displacement"].max() < 1e-3 and 1e-5 < hold["displacement"].max() < 1e-3
    # the holdout's voltage column (kV in the file) follows Eq. 42 at 25 kV, 10 Hz
    expected = 25e3 / 2 * (1 + np.sin(2 * np.pi * 10.0 * hold.time + 1.5 * np.pi))
    np.testing.assert_allclose(hold["voltage"], expected, atol=1e-3)
    for name in exp.fit.free:
        lo, hi = exp.fit.bounds[name]
        assert lo <= exp.parameters()[name] <= hi


# ---------------------------------------------------------------------------
# CSV errors: file, row (header = 1) and column named
# ---------------------------------------------------------------------------


def test_missing_csv_file(tmp_path):
    raises(["nope.csv", "not found"], load_trace_csv, tmp_path / "nope.csv")
    toml = TOML.replace('file = "run.csv"', 'file = "missing.csv"')
    raises(["exp.toml", "missing.csv", "not found"], load_experiment, write(tmp_path, toml))


def test_missing_toml_file(tmp_path):
    raises(["absent.toml", "not found"], load_experiment, tmp_path / "absent.toml")


def test_missing_channel_mapping_in_experiment(tmp_path):
    toml = TOML.replace('columns = { time = "t_ms", displacement = "disp_mm", voltage = "U_kV" }',
                        'columns = { displacement = "disp_mm", voltage = "U_kV" }')
    toml = toml.replace('units = { time = "ms", displacement = "mm", voltage = "kV" }',
                        'units = { displacement = "mm", voltage = "kV" }')
    raises(["run.csv", "exp.toml", "required channel(s) time", "present columns: t_ms, disp_mm, U_kV, note"],
           load_experiment, write(tmp_path, toml))


def test_non_numeric_cell(tmp_path):
    bad = CSV.replace("2,1.0,3.0,x", "2,1.o,3.0,x")
    p = tmp_path / "run.csv"
    p.write_text(bad)
    # header is row 1; data rows 0, 1, 2 are rows 2, 3, 4 (the first-line comment is not counted)
    e = raises(["run.csv", "row 4", "column 'disp_mm'", "'1.o'"], load_trace_csv, p,
               {"time": "t_ms", "displacement": "disp_mm"})
    assert e.row == 4 and e.line == 5 and "line 5" in str(e)
    # the same error surfaces through load_experiment
    raises(["run.csv", "row 4", "disp_mm", "'1.o'"], load_experiment, write(tmp_path, TOML, bad))


def test_unknown_unit_lists_known(tmp_path):
    p = tmp_path / "run.csv"
    p.write_text(CSV)
    raises(["run.csv", "unknown unit 'mmm'", "known units: m, cm, mm, um"], load_trace_csv, p,
           {"time": "t_ms", "displacement": "disp_mm"}, {"displacement": "mmm"})
    # a unit of the wrong kind is unknown for that channel
    raises(["run.csv", "unknown unit 'kV' for channel 'displacement'"], load_trace_csv, p,
           {"time": "t_ms", "displacement": "disp_mm"}, {"displacement": "kV"})
    toml = TOML.replace('voltage = "kV" }', 'voltage = "kv" }')
    raises(["run.csv", "exp.toml", "unknown unit 'kv'", "did you mean 'kV'"], load_experiment,
           write(tmp_path, toml))


# ---------------------------------------------------------------------------
# TOML errors: file and section/key named
# ---------------------------------------------------------------------------


def test_invalid_toml(tmp_path):
    raises(["exp.toml", "invalid TOML", "line"], load_experiment, write(tmp_path, TOML + "\nfoo = = 1\n"))


def test_empty_toml(tmp_path):
    raises(["exp.toml", "empty"], load_experiment, write(tmp_path, "  \n"))


def test_unknown_section(tmp_path):
    e = raises(["exp.toml", "unknown section [solvr]", "did you mean 'solver'",
                "allowed: experiment, geometry, material, fit, solver, effects, traces"],
               load_experiment, write(tmp_path, TOML.replace("[solver]", "[solvr]")))
    line = TOML.splitlines().index("[solver]") + 1
    assert f"line {line}" in str(e)  # where [solvr] is


def test_unknown_key(tmp_path):
    toml = TOML.replace("dt = 1e-4", "td = 1e-4")
    e = raises(["exp.toml", "unknown key 'td' in [solver]", "allowed: dt, dt_min"], load_experiment,
               write(tmp_path, toml))
    assert e.key == "solver.td" and f"line {TOML.splitlines().index('dt = 1e-4') + 1}" in str(e)
    raises(["exp.toml", "unknown key 'L_t'", "for scenario 'rolled'", "allowed: h, r, L, mesh, probe"],
           load_experiment, write(tmp_path, TOML.replace("L = 8e-3", "L_t = 8e-3")))
    raises(["exp.toml", "unknown key 'colums'", "did you mean 'columns'"], load_experiment,
           write(tmp_path, TOML.replace("columns = {", "colums = {")))
    raises(["exp.toml", "unknown key 'tau' in viscous unit 1", "allowed: mu, K, Jm, eta"], load_experiment,
           write(tmp_path, TOML.replace("eta = 400.0", "tau = 400.0")))


def test_unknown_scenario(tmp_path):
    raises(["exp.toml", "unknown scenario 'rolld'", "did you mean 'rolled'",
            "block, rolled, torsional, uniaxial"],
           load_experiment, write(tmp_path, TOML.replace('scenario = "rolled"', 'scenario = "rolld"')))


@pytest.mark.parametrize("name, hint", [
    ("mu_2", "1 viscous unit(s): mu_1)"),
    ("eta_0", "numbered from 1"),
    ("eta_inf", "known: mu_inf"),
    ("Mu_1", "did you mean 'mu_1'"),
])
def test_unknown_free_parameter(tmp_path, name, hint):
    toml = TOML.replace('free = ["mu_1", "eta_1"]', f'free = ["mu_1", "{name}"]')
    raises(["exp.toml", f"unknown parameter '{name}'", hint, "fit.free"], load_experiment, write(tmp_path, toml))


def test_duplicate_free_parameter(tmp_path):
    toml = TOML.replace('free = ["mu_1", "eta_1"]', 'free = ["mu_1", "mu_1"]')
    raises(["exp.toml", "duplicate free parameter", "mu_1"], load_experiment, write(tmp_path, toml))


@pytest.mark.parametrize("bounds, msg", [
    ("[1e6, 1e3]", "lower < upper"),
    ("[1e3, 1e3]", "lower < upper"),
    ("[1e5, 1e6]", "initial value mu_1 = 80000 lies outside its bounds"),
    ("[1e3]", "must be [lower, upper]"),
])
def test_bad_bounds(tmp_path, bounds, msg):
    toml = TOML.replace("mu_1 = [1e3, 1e6]", f"mu_1 = {bounds}")
    e = raises(["exp.toml", "fit.bounds.mu_1", msg], load_experiment, write(tmp_path, toml))
    assert e.key == "fit.bounds.mu_1"


RESULT = """
[fit.result]
mu_1 = { value = 80e3, unit = "Pa", stderr = 1.5e3, rel_stderr = 0.01875, initial = 9e4 }
"""


def test_fit_result_table_is_kept_and_checked(tmp_path):
    toml = TOML.replace("[solver]", RESULT + "\n[solver]")
    exp = load_experiment(write(tmp_path, toml))
    assert exp.fit.result == {"mu_1": {"value": 80e3, "unit": "Pa", "stderr": 1.5e3, "rel_stderr": 0.01875,
                                       "initial": 9e4}}
    assert "result" not in exp.fit.options and exp.parameters()["mu_1"] == 80e3
    for old, new, msg in (("mu_1 = {", "mu_9 = {", "unknown parameter 'mu_9'"),
                          ("stderr = 1.5e3", "sterr = 1.5e3", "unknown key 'sterr'"),
                          ('unit = "Pa"', "unit = 1", "'unit' must be a string"),
                          ("initial = 9e4", 'initial = "9e4"', "'initial' must be a number")):
        raises(["exp.toml", "fit.result", msg], load_experiment, write(tmp_path, toml.replace(old, new)))


def test_bounds_on_unknown_parameter(tmp_path):
    toml = TOML.replace("mu_1 = [1e3, 1e6]", "mu_3 = [1e3, 1e6]")
    raises(["exp.toml", "unknown parameter 'mu_3'"], load_experiment, write(tmp_path, toml))


@pytest.mark.parametrize("section", ["experiment", "material", "traces"])
def test_missing_required_section(tmp_path, section):
    doc = TOML
    if section == "traces":
        doc = doc[: doc.index("[[traces]]")]
    elif section == "material":
        doc = doc[: doc.index("[material]")] + doc[doc.index("[fit]"):].replace(
            'free = ["mu_1", "eta_1"]', "free = []").replace("mu_1 = [1e3, 1e6]\neta_1 = [1.0, 1e4]\n", "")
    else:
        doc = doc[doc.index("[geometry]"):]
    raises(["exp.toml", f"missing required section [{section}]"], load_experiment, write(tmp_path, doc))


def test_missing_geometry_and_required_keys(tmp_path):
    doc = TOML[: TOML.index("[geometry]")] + TOML[TOML.index("[material]"):]
    raises(["exp.toml", "missing required section [geometry]", "rolled"], load_experiment, write(tmp_path, doc))
    raises(["exp.toml", "missing required key 'r'"], load_experiment,
           write(tmp_path, TOML.replace("r = 2e-3\n", "")))
    raises(["exp.toml", "missing required key 'eps'"], load_experiment,
           write(tmp_path, TOML.replace("eps = 3.4e-11\n", "")))
    raises(["exp.toml", "viscous unit 1 lacks 'eta'"], load_experiment,
           write(tmp_path, TOML.replace("eta = 400.0\n", "").replace(', "eta_1"', "").replace("eta_1 = [1.0, 1e4]\n", "")))
    # the block takes L, or all of lx, ly, lz
    block = TOML.replace('scenario = "rolled"', 'scenario = "block"').replace("h = 2e-3\nr = 2e-3\nL = 8e-3\n", "lx = 1e-3\n")
    raises(["exp.toml", "missing required key 'ly' for scenario 'block' (give L, or all of lx, ly, lz)"],
           load_experiment, write(tmp_path, block))
    # the uniaxial test may leave [geometry] out
    doc_u = doc.replace('scenario = "rolled"', 'scenario = "uniaxial"')
    raises(["exp.toml", "required channel(s) stretch, stress not mapped"], load_experiment, write(tmp_path, doc_u))


@pytest.mark.parametrize("old, new, msg", [
    ("mu_inf = 81e3", "mu_inf = -81e3", "'mu_inf' = -81000.0 must be > 0"),
    ("mu_inf = 81e3", 'mu_inf = "81 kPa"', "'mu_inf' must be a finite number"),
    ("mesh = [2, 8, 1]", "mesh = [2, 8]", "'mesh' must be a list of three integers"),
    ("rho_inf = 0.8", "rho_inf = 1.5", "'rho_inf' = 1.5 must be <= 1.0"),
    ('role = "fit"', 'role = "train"', "unknown role 'train'"),
    ('name = "test-exp"', "name = 3", "'name' must be a non-empty string"),
])
def test_bad_values(tmp_path, old, new, msg):
    raises(["exp.toml", msg], load_experiment, write(tmp_path, TOML.replace(old, new)))


def test_loading_validation(tmp_path):
    base = TOML.replace('columns = { time = "t_ms", displacement = "disp_mm", voltage = "U_kV" }',
                        'columns = { time = "t_ms", displacement = "disp_mm" }')
    base = base.replace('units = { time = "ms", displacement = "mm", voltage = "kV" }',
                        'units = { time = "ms", displacement = "mm" }')
    raises(["exp.toml", "no voltage column and no 'loading' table"], load_experiment, write(tmp_path, base))
    mismatch = base + 'loading = { kind = "sine", phi_max = 4.5e3, freq = 10.0 }\n'
    raises(["exp.toml", "loading freq = 10 disagrees with conditions freq = 30"], load_experiment,
           write(tmp_path, mismatch))
    unknown = base + 'loading = { kind = "sinus", phi_max = 4.5e3, freq = 30.0 }\n'
    raises(["exp.toml", "unknown loading kind 'sinus'", "did you mean 'sine'"], load_experiment,
           write(tmp_path, unknown))
    missing = base + 'loading = { kind = "sine", phi_max = 4.5e3 }\n'
    raises(["exp.toml", "needs 'freq'"], load_experiment, write(tmp_path, missing))
    ok = base + 'loading = { kind = "sine", phi_max = 4.5e3, freq = 30.0 }\n'
    assert load_experiment(write(tmp_path, ok)).traces[0].loading["phase"] == pytest.approx(1.5 * math.pi)


def test_uniaxial_needs_stretch_and_stress(tmp_path):
    toml = textwrap.dedent("""\
        [experiment]
        name = "vhb"
        scenario = "uniaxial"
        [material]
        mu_inf = 50e3
        K_inf = 1e9
        Jm_inf = 100.0
        eps = 4.1e-11
        rho = 960.0
        [[traces]]
        file = "u.csv"
        units = { stress = "kPa" }
        """)
    exp = load_experiment(write(tmp_path, toml, "stretch,stress\n1.0,0\n2.0,30\n", csv_name="u.csv"))
    np.testing.assert_allclose(exp.traces[0]["stress"], [0.0, 30e3])
    assert exp.geometry == {}
    raises(["u.csv", "required channel(s) stress"], load_experiment,
           write(tmp_path, toml.replace('units = { stress = "kPa" }', ""), "stretch,force\n1.0,0\n2.0,30\n",
                 csv_name="u.csv"))


def test_effects_and_qualified_parameters(tmp_path):
    toml = TOML.replace("[solver]", textwrap.dedent("""\
        [effects.electrode_stiffness]
        thickness = 1e-5
        modulus = 1e6
        [effects.off_one]
        enabled = false
        x = 1.0
        [effects]
        leakage = true

        [solver]"""))
    # TOML forbids defining [effects] after [effects.x]; use a dotted key instead
    toml = toml.replace("[effects]\nleakage = true\n", "")
    toml = toml.replace("[effects.off_one]", "[effects.leakage]\n[effects.off_one]")
    toml = toml.replace('free = ["mu_1", "eta_1"]', 'free = ["mu_1", "effects.electrode_stiffness.modulus", "geometry.h"]')
    toml = toml.replace("eta_1 = [1.0, 1e4]", "\"effects.electrode_stiffness.modulus\" = [1e3, 1e9]")
    exp = load_experiment(write(tmp_path, toml))
    assert set(exp.effects) == {"electrode_stiffness", "leakage"}
    assert exp.effects["electrode_stiffness"] == {"thickness": 1e-5, "modulus": 1e6}
    assert exp.fit.free == ("mu_1", "effects.electrode_stiffness.modulus", "geometry.h")
    assert exp.fit.bounds["effects.electrode_stiffness.modulus"] == (1e3, 1e9)


def test_duplicate_trace_names(tmp_path):
    toml = TOML + '\n[[traces]]\nfile = "run.csv"\nloading = { kind = "constant", phi = 0.0 }\n' \
                  'columns = { time = "t_ms", displacement = "disp_mm" }\n'
    raises(["exp.toml", "duplicate trace name 'run'"], load_experiment, write(tmp_path, toml))
    ok = toml.replace('file = "run.csv"\nloading', 'file = "run.csv"\nname = "second"\nrole = "holdout"\nloading')
    exp = load_experiment(write(tmp_path, ok))
    assert [t.name for t in exp.traces] == ["run", "second"] and exp.trace("second").role == "holdout"


def test_every_registered_scenario_has_a_geometry_schema():
    from fitting import schema

    assert set(schema.GEOMETRY_KEYS) == set(schema.SCENARIOS) == set(schema.GEOMETRY_REQUIRED) == set(
        schema.TRACE_REQUIRED)
    assert set(schema.DYNAMIC_SCENARIOS) | set(schema.GEOMETRY_OPTIONAL) <= set(schema.SCENARIOS)
