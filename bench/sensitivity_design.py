"""The sensitivity notebook's fit-scale checks and the Fig. 20 design question, as a script
(issue 11, point 5), for runs outside Jupyter:

    python bench/sensitivity_design.py            # 4 x 8 x 1 checks + design study (tens of minutes on 2 cores)
    DEJAX_SMALL=1 python bench/sensitivity_design.py

Prints the tables the notebook shows: jacfwd against central
differences and reverse mode (jax.vjp) against forward mode per output, with wall times;
projected Adam on log h against a brute-force sweep of h for x_max at phi_m/h = 2.5e7 V/m.
"""

import os
import time

import numpy as np
import optax

from fitting import sensitivity as S

SMALL = os.environ.get("DEJAX_SMALL", "0") not in ("", "0")


def check(shape, names, cycles, model="IV"):
    setup = S.Setup(shape=shape, model=model, freq=30.0, phi_max=50e3, t_end=cycles / 30.0, dt=1 / (30.0 * 67), tol=1e-10)
    params = S.default_params(setup)
    tic = time.perf_counter(); res = S.sensitivity(params, names, setup); t_all = time.perf_counter() - tic
    tic = time.perf_counter(); fd = S.finite_differences(params, names, setup, rel_step=1e-4); t_fd = time.perf_counter() - tic
    rev = S.reverse_check(params, names, setup, jacobian=res["jacobian"])
    rows = ["| output | judged entry: value | p/y dy/dp | jacfwd vs central FD | reverse vs forward | not judged (tiny) |",
            "|---|---|---|---|---|---|"]
    table = S.check_rows(res, fd, rev)
    worst = max((r["fd_error"] for r in table if r["fd_error"] is not None), default=0.0)
    for r in table:
        e = "-" if r["fd_error"] is None else f"{r['fd_error']:.1e}"
        rows.append(f"| {r['output']} | [{r['row']}] {r['value']:.5g} | {r['rel_sens']:+.3g} ({r['param']}) | {e} | "
                    f"{r['rev_error']:.1e} | {', '.join(r['tiny']) or '-'} |")
    mesh = "x".join(map(str, shape))
    print(f"**{mesh}, Model {model}, {cycles} cycle(s), {len(setup.times) - 1} steps, parameters {', '.join(names)}**\n\n" + "\n".join(rows))
    print(f"{mesh}: one simulation {res['seconds_simulation']:.2f} s; jacfwd ({len(names)} parameters) {res['seconds_jacobian']:.2f} s "
          f"({res['ratio']:.1f} x); one reverse pass {rev['seconds_reverse']:.2f} s ({rev['seconds_reverse'] / res['seconds_simulation']:.1f} x); "
          f"{2 * len(names)} central differences {t_fd:.1f} s; first calls (compilation) {sum(res['first_call_seconds']) + rev['compile_seconds']:.0f} s")
    print(f"worst jacfwd vs FD over all judged entries: {worst:.1e} (target 1e-4; entries with |p dy/dp| < 1e-3 max|y| "
          "are not judged: their differences measure round-off)")
    return res, fd, rev, setup

if SMALL:
    checks = {"1x4x1": check((1, 4, 1), ("h", "mu_inf"), 1, model="I")}
else:
    checks = {"4x8x1": check((4, 8, 1), ("h", "L", "r", "mu_inf", "Jm_inf", "mu_1", "eta_1", "mu_4", "eta_4"), 2)}

CYC = 2 if SMALL else 3
dsetup = S.Setup(shape=(1, 4, 1) if SMALL else (4, 8, 1), model="IV", freq=30.0, t_end=CYC / 30.0, dt=1 / (30.0 * 67),
                 tol=1e-8, field=2.5e7)
dparams = S.default_params(dsetup)
H_LO, H_HI = 1e-3, 14e-3

def objective(h):
    r = S.sensitivity(dict(dparams, h=h), ("h",), dsetup, timing=False)
    return float(r["values"]["x_max"][-1]), float(r["jacobian"]["x_max"][-1, 0])

tic = time.perf_counter()
u = np.log(8e-3)  # start: the middle of the paper's range
opt = optax.adam(0.3); state = opt.init(np.array([u]))
path = []
converged = False
for k in range(4 if SMALL else 20):
    h = float(np.exp(u)); xm, g = objective(h)
    path.append((h, xm, g))
    print(f"iteration {k:2d}: h = {1e3 * h:7.3f} mm, x_max = {1e3 * xm:.5f} mm, dx_max/dh = {g:+.4e} (m/m)")
    upd, state = opt.update(-np.array([g * h]), state)  # ascent on u = log h: d x_max / du = h dx_max/dh
    u_new = float(np.clip(u + upd[0], np.log(H_LO), np.log(H_HI)))
    if abs(u_new - u) < 1e-3:
        converged = True
        break
    u = u_new
t_grad = time.perf_counter() - tic
h_opt, x_opt, g_opt = path[-1]
print(f"gradient ascent: h* = {1e3 * h_opt:.3f} mm, x_max = {1e3 * x_opt:.5f} mm after {len(path)} evaluations in {t_grad:.0f} s; "
      f"at h* dx_max/dh = {g_opt:+.3e}: " + ("not converged (iteration limit)" if not converged else
      "< 0 at the lower bound, so the bound is the constrained optimum (KKT)" if g_opt < 0 and h_opt <= H_LO * 1.001 else
      "> 0 at the upper bound (KKT)" if g_opt > 0 and h_opt >= H_HI * 0.999 else "an interior stationary point"))

hs = np.array([1.0, 2.0, 4.0, 8.0, 14.0] if SMALL else [1.0, 1.5, 2.0, 3.0, 4.0, 5.0, 6.0, 8.0, 10.0, 12.0, 14.0]) * 1e-3
f_val = S._compiled(("h",), dsetup, "value")
base = {k: float(v) for k, v in dparams.items()}
tic = time.perf_counter()
sweep = np.array([float(f_val(np.array([h]), base)["x_max"][-1]) for h in hs])
t_sweep = time.perf_counter() - tic
i = int(np.argmax(sweep))
print(f"brute-force sweep ({hs.size} simulations, {t_sweep:.0f} s): best h = {1e3 * hs[i]:.2f} mm, x_max = {1e3 * sweep[i]:.5f} mm")
print(f"gradient ascent ({len(path)} simulations + derivatives, {t_grad:.0f} s): h* = {1e3 * h_opt:.3f} mm, x_max = {1e3 * x_opt:.5f} mm")
