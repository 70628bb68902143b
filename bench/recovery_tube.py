"""Recovery of Model IV's viscous parameters from synthetic x_P traces of the tube (issue 11,
point 4), and which extra experiment would separate what the traces do not.

    python bench/recovery_tube.py [--mesh 4x8x1] [--cycles 2] [--steps-per-cycle 100]
                                  [--starts 3] [--max-evals 25] [--freqs 10,30] [--json recovery.json]

1. Truth: the tube (h = r = 2 mm, L = 8 mm) with Model IV (Table 2: mu_inf = 72 kPa, mu_s = 10,
   10, 80, 80 kPa, eta_s = 5000, 2000, 300, 100 Pa s), the sine voltage of Eq. 42 to 50 kV at
   10 Hz and 30 Hz, ``--cycles`` cycles each, ``--steps-per-cycle`` steps per cycle. x_P at every
   step, plus Gaussian noise of 1 % of the trace's peak |x_P| (seeded).
2. Fits of mu_1..mu_4, eta_1..eta_4 (``fitting.fit``, Levenberg-Marquardt in log p on the
   forward-mode Jacobian; the forward is the one that made the traces, ``RolledForward``,
   so the test is one of identifiability, not of discretization) from ``--starts`` starts,
   each parameter multiplied by a random factor in [1/3, 3]. Each start: the estimates against
   the truth in standard errors, and the pairs with |correlation| > 0.95.
3. Design: the Fisher information of log p at the truth (J^T J / sigma^2, J the Jacobian of
   x_P) for the two traces, then with one more trace of the same length at 1, 3, 100 Hz
   (50 kV) or at 30 Hz and 25 kV: the largest |correlation| and the standard errors of ln p each
   would leave. The candidate that lowers the largest standard error most (the worst-determined
   parameter) is the experiment to add.
"""
from __future__ import annotations

import argparse
import json
import time

import jax
import jax.numpy as jnp
import numpy as np

from dejax import parameters, scenarios
from fitting import fit as F
from fitting.experiment import RolledForward
from fitting.traces import from_samples

FREE = tuple(f"{k}_{i}" for k in ("mu", "eta") for i in range(1, 5))
NOISE = 0.01  # of each trace's peak |x_P|
PHI_MAX = 50e3  # V
CANDIDATES = ((1.0, PHI_MAX), (3.0, PHI_MAX), (100.0, PHI_MAX), (30.0, 25e3))  # (Hz, V)


def truth() -> dict:
    return {k: float(v) for k, v in parameters.flat(scenarios.rolled_material("IV")).items()}


def loading_data(freq, phi_max, cycles, steps_per_cycle) -> dict:
    """The forward's data: the grid, the Eq. 42 voltage on it, x_P observed at every step."""
    n = cycles * steps_per_cycle
    t = np.linspace(0.0, cycles / freq, n + 1)
    v = 0.5 * phi_max * (1.0 + np.sin(2.0 * np.pi * freq * t + 1.5 * np.pi))
    return dict(times=jnp.asarray(t), volt_t=jnp.asarray(t), volt_v=jnp.asarray(v), t_obs=jnp.asarray(t[1:]))


def synthetic_trace(forward, params, freq, phi_max, cycles, spc, rng):
    data = loading_data(freq, phi_max, cycles, spc)
    x = np.asarray(forward({k: jnp.asarray(v) for k, v in params.items()}, data))
    sigma = NOISE * np.max(np.abs(x))
    y = x + sigma * rng.standard_normal(x.shape)
    trace = from_samples(f"x_P_{freq:g}Hz_{phi_max / 1e3:g}kV", y, data=data, t=np.asarray(data["t_obs"]),
                         x=np.asarray(data["volt_v"])[1:], unit="m", ylabel="x_P (m)", xlabel="voltage (V)")
    return trace, sigma


def jacobian_at(forward, params, data):
    """d x_P / d log p of the free parameters at ``params`` (n_obs, 8)."""
    def f(logp):
        p = dict({k: jnp.asarray(v) for k, v in params.items()}, **{k: jnp.exp(logp[i]) for i, k in enumerate(FREE)})
        return forward(p, data)

    logp = jnp.log(jnp.asarray([params[k] for k in FREE]))
    return np.asarray(jax.jit(jax.jacfwd(f))(logp))


def correlation(fisher):
    cov = np.linalg.inv(fisher)
    s = np.sqrt(np.diag(cov))
    return cov / np.outer(s, s), s


def worst_pair(corr):
    c = np.abs(corr - np.eye(len(corr)))
    i, j = np.unravel_index(np.argmax(c), c.shape)
    return float(corr[i, j]), FREE[i], FREE[j]


def main():
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--mesh", default="4x8x1")
    ap.add_argument("--cycles", type=int, default=2)
    ap.add_argument("--steps-per-cycle", type=int, default=100)
    ap.add_argument("--starts", type=int, default=3)
    ap.add_argument("--max-evals", type=int, default=25)
    ap.add_argument("--freqs", default="10,30", help="comma-separated frequencies of the fitted traces (Hz)")
    ap.add_argument("--seed", type=int, default=11)
    ap.add_argument("--json", default=None)
    a = ap.parse_args()
    shape = tuple(int(s) for s in a.mesh.split("x"))
    freqs = tuple(float(f) for f in a.freqs.split(","))
    rng = np.random.default_rng(a.seed)
    p_true = truth()
    fw = RolledForward(4, 2e-3, 2e-3, 8e-3, shape=shape)
    tic = time.perf_counter()
    made = [synthetic_trace(fw, p_true, f, PHI_MAX, a.cycles, a.steps_per_cycle, rng) for f in freqs]
    traces = [t for t, _ in made]
    print(f"tube {a.mesh}, Model IV, {a.cycles} cycles x {a.steps_per_cycle} steps at {freqs} Hz, "
          f"{PHI_MAX / 1e3:g} kV, noise {100 * NOISE:g} % of the peak; traces made in {time.perf_counter() - tic:.0f} s")
    bounds = {k: (p_true[k] / 30.0, p_true[k] * 30.0) for k in FREE}
    out = dict(mesh=a.mesh, cycles=a.cycles, steps_per_cycle=a.steps_per_cycle, truth={k: p_true[k] for k in FREE},
               starts=[])
    for s in range(a.starts):
        factors = np.exp(rng.uniform(np.log(1 / 3), np.log(3), len(FREE)))
        p0 = dict(p_true, **{k: p_true[k] * f for k, f in zip(FREE, factors)})
        tic = time.perf_counter()
        res = F.fit(fw, p0, FREE, bounds, traces, method="lm", max_evals=a.max_evals, verbose=False)
        wall = time.perf_counter() - tic
        z = {k: (res.params[k] - p_true[k]) / res.stderr[k] for k in FREE}
        pairs = [(FREE[i], FREE[j], float(res.corr[i, j])) for i in range(len(FREE)) for j in range(i + 1, len(FREE))
                 if abs(res.corr[i, j]) > 0.95]
        ok = all(abs(v) <= 3.0 for v in z.values())
        print(f"\nstart {s + 1}: factors {np.round(factors, 2).tolist()}; loss {res.loss0:.4g} -> {res.loss:.4g}, "
              f"{res.n_evals} evaluations, {wall:.0f} s; every parameter within 3 standard errors: {ok}")
        print(f"{'parameter':>9} {'truth':>10} {'start':>10} {'fitted':>10} {'std. err.':>10} {'(fit-truth)/se':>14}")
        for k in FREE:
            print(f"{k:>9} {p_true[k]:10.4g} {p0[k]:10.4g} {res.params[k]:10.4g} {res.stderr[k]:10.3g} {z[k]:14.2f}")
        print("pairs with |correlation| > 0.95: " + (", ".join(f"{i}-{j} {c:+.3f}" for i, j, c in pairs) or "none"))
        out["starts"].append(dict(factors=factors.tolist(), params={k: res.params[k] for k in FREE},
                                  stderr={k: res.stderr[k] for k in FREE}, z=z, within_3se=ok, pairs=pairs,
                                  loss=res.loss, loss0=res.loss0, n_evals=res.n_evals, wall_s=wall))
    # design: Fisher information of log p at the truth, with and without one more trace
    tic = time.perf_counter()
    sig = [s for _, s in made]
    fisher = sum(J.T @ J / s ** 2 for J, s in
                 ((jacobian_at(fw, p_true, t.data), s) for t, s in zip(traces, sig)))
    corr, se = correlation(fisher)
    c, i, j = worst_pair(corr)
    rows = [(" + ".join(f"{f:g}" for f in freqs) + " Hz, 50 kV (fitted)", c, i, j, se)]
    for f, phi in CANDIDATES:
        data = loading_data(f, phi, a.cycles, a.steps_per_cycle)
        J = jacobian_at(fw, p_true, data)
        x = np.asarray(fw({k: jnp.asarray(v) for k, v in p_true.items()}, data))
        s = NOISE * np.max(np.abs(x))
        corr_c, se_c = correlation(fisher + J.T @ J / s ** 2)
        c, i, j = worst_pair(corr_c)
        rows.append((f"+ {f:g} Hz, {phi / 1e3:g} kV", c, i, j, se_c))
    print(f"\ndesign (Fisher information of log p at the truth, noise {100 * NOISE:g} % of each trace's peak; "
          f"{time.perf_counter() - tic:.0f} s): worst correlation and standard errors of ln p")
    print(f"{'experiment':<28} {'worst |corr|':>12} {'pair':>14} " + " ".join(f"{k:>7}" for k in FREE))
    for name, c, i, j, se_ in rows:
        print(f"{name:<28} {abs(c):12.4f} {i + '-' + j:>14} " + " ".join(f"{v:7.3f}" for v in se_))
    # criterion: the largest standard error of ln p (the worst-determined parameter) after the addition
    best = min(rows[1:], key=lambda r: float(np.max(r[4])))
    k = int(np.argmax(rows[0][4]))
    print(f"the extra experiment that separates the parameters best (smallest largest standard error of ln p): "
          f"{best[0].lstrip('+ ')}: largest s.e. of ln p {np.max(rows[0][4]):.3g} ({FREE[k]}) -> {np.max(best[4]):.3g} "
          f"({FREE[int(np.argmax(best[4]))]}); worst |correlation| {abs(rows[0][1]):.4f} -> {abs(best[1]):.4f}")
    out["design"] = [dict(experiment=n, worst_corr=c, pair=[i, j], se_log=list(map(float, s))) for n, c, i, j, s in rows]
    if a.json:
        with open(a.json, "w") as fh:
            json.dump(out, fh, indent=2, default=float)


if __name__ == "__main__":
    main()
