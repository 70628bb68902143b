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
   the truth in standard errors, and the pairs with |correlation| > 0.95. The four units are
   exchangeable (swapping two units' (mu, eta) leaves x_P unchanged), so the parameters are
   identifiable only up to a relabelling: the fitted units are put in the truth's order, by
   relaxation time tau_s = eta_s / mu_s (longest first), before they are compared
   (``--skip-starts k`` draws and skips the first k starts: one start per run).
3. Design: the Fisher information of ln p at the truth (J^T J / sigma^2, J the Jacobian of
   x_P) of the fitted traces: its least determined combinations (eigenvectors), and, in greedy
   rounds, one more trace of the same number of steps at 0.3, 1, 3, 100 or 300 Hz (50 kV), at
   30 Hz and 25 kV, or a creep test (50 kV ramped in 20 ms, held 2 s): the largest
   |correlation| and the standard errors of ln p each would leave. Each round adds the
   candidate that lowers the largest standard error most (the worst-determined parameter),
   until it is below ``--target-se`` (``--starts 0``: the design alone).
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
CANDIDATES = ((0.3, PHI_MAX), (1.0, PHI_MAX), (3.0, PHI_MAX), (100.0, PHI_MAX), (300.0, PHI_MAX),
              (30.0, 25e3), (0.0, PHI_MAX))  # (Hz, V); 0 Hz: a creep test (``creep_data``)
CREEP_RAMP, CREEP_HOLD = 0.02, 2.0  # s


def truth() -> dict:
    return {k: float(v) for k, v in parameters.flat(scenarios.rolled_material("IV")).items()}


def loading_data(freq, phi_max, cycles, steps_per_cycle) -> dict:
    """The forward's data: the grid, the Eq. 42 voltage on it, x_P observed at every step."""
    n = cycles * steps_per_cycle
    t = np.linspace(0.0, cycles / freq, n + 1)
    v = 0.5 * phi_max * (1.0 + np.sin(2.0 * np.pi * freq * t + 1.5 * np.pi))
    return dict(times=jnp.asarray(t), volt_t=jnp.asarray(t), volt_v=jnp.asarray(v), t_obs=jnp.asarray(t[1:]))


def creep_data(phi_max, n_steps) -> dict:
    """A creep test of ``n_steps`` steps: the voltage ramped to phi_max over CREEP_RAMP (a fifth
    of the steps) and held until CREEP_RAMP + CREEP_HOLD (about 4 relaxation times of the slowest
    unit of Model IV), x_P observed at every step."""
    n_ramp = n_steps // 5
    t = np.concatenate([np.linspace(0.0, CREEP_RAMP, n_ramp + 1),
                        np.linspace(CREEP_RAMP, CREEP_RAMP + CREEP_HOLD, n_steps - n_ramp + 1)[1:]])
    v = phi_max * np.minimum(t / CREEP_RAMP, 1.0)
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


def relabelled(params, stderr, corr):
    """The fitted units in the truth's order (relaxation time eta_s / mu_s, longest first), with
    their standard errors and correlations permuted alike: (params, stderr, corr, order)."""
    tau = [params[f"eta_{i}"] / params[f"mu_{i}"] for i in range(1, 5)]
    order = [int(i) + 1 for i in np.argsort(tau)[::-1]]  # fitted unit at each truth position
    new = {f"{k}_{pos}": f"{k}_{src}" for k in ("mu", "eta") for pos, src in enumerate(order, 1)}
    idx = [FREE.index(new[k]) for k in FREE]
    return ({k: params[new[k]] for k in FREE}, {k: stderr[new[k]] for k in FREE},
            np.asarray(corr)[np.ix_(idx, idx)], order)


def combinations(fisher, label, n=3):
    """Print the n least determined combinations of ln p (the Fisher information's eigenvectors of
    smallest eigenvalue; standard error 1 / sqrt(eigenvalue)) and the standard errors of the
    moduli sums of the slow (1, 2) and fast (3, 4) pairs, ln(mu_1 + mu_2) and ln(mu_3 + mu_4)."""
    lam, vec = np.linalg.eigh(fisher)
    print(f"\nleast determined combinations of ln p, {label}:")
    for m in range(n):
        terms = sorted(((float(v), k) for v, k in zip(vec[:, m], FREE)), key=lambda t: -abs(t[0]))
        print(f"  s.e. {1 / np.sqrt(lam[m]):8.3g}: " + " ".join(f"{v:+.2f} ln {k}" for v, k in terms if abs(v) > 0.1))
    cov, p = np.linalg.inv(fisher), truth()
    for i, j in ((1, 2), (3, 4)):
        g = np.zeros(len(FREE))
        for k in (i, j):
            g[FREE.index(f"mu_{k}")] = p[f"mu_{k}"] / (p[f"mu_{i}"] + p[f"mu_{j}"])
        print(f"  s.e. of ln(mu_{i} + mu_{j}): {np.sqrt(g @ cov @ g):.3g}")


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
    ap.add_argument("--target-se", type=float, default=0.3,
                    help="design: add experiments until the largest standard error of ln p is below this")
    ap.add_argument("--skip-starts", type=int, default=0, help="draw and skip the first k starts")
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
    for s in range(a.skip_starts + a.starts):
        factors = np.exp(rng.uniform(np.log(1 / 3), np.log(3), len(FREE)))
        if s < a.skip_starts:
            continue
        p0 = dict(p_true, **{k: p_true[k] * f for k, f in zip(FREE, factors)})
        tic = time.perf_counter()
        res = F.fit(fw, p0, FREE, bounds, traces, method="lm", max_evals=a.max_evals, verbose=False)
        wall = time.perf_counter() - tic
        fitted, stderr, corr_fit, order = relabelled(res.params, res.stderr, res.corr)
        z = {k: (fitted[k] - p_true[k]) / stderr[k] for k in FREE}
        pairs = [(FREE[i], FREE[j], float(corr_fit[i, j])) for i in range(len(FREE)) for j in range(i + 1, len(FREE))
                 if abs(corr_fit[i, j]) > 0.95]
        ok = all(abs(v) <= 3.0 for v in z.values())
        print(f"\nstart {s + 1}: factors {np.round(factors, 2).tolist()}; loss {res.loss0:.4g} -> {res.loss:.4g}, "
              f"{res.n_evals} evaluations, {wall:.0f} s; every parameter within 3 standard errors: {ok}")
        print(f"fitted units in the truth's order (by relaxation time): {order}")
        print(f"{'parameter':>9} {'truth':>10} {'start':>10} {'fitted':>10} {'std. err.':>10} {'(fit-truth)/se':>14}")
        for k in FREE:
            print(f"{k:>9} {p_true[k]:10.4g} {p0[k]:10.4g} {fitted[k]:10.4g} {stderr[k]:10.3g} {z[k]:14.2f}")
        print("pairs with |correlation| > 0.95: " + (", ".join(f"{i}-{j} {c:+.3f}" for i, j, c in pairs) or "none"))
        out["starts"].append(dict(start=s + 1, factors=factors.tolist(), params=fitted, stderr=stderr,
                                  relabel=order, z=z, within_3se=ok, pairs=pairs,
                                  loss=res.loss, loss0=res.loss0, n_evals=res.n_evals, wall_s=wall))
    # design: Fisher information of log p at the truth, with and without one more trace
    tic = time.perf_counter()
    sig = [s for _, s in made]
    fisher = sum(J.T @ J / s ** 2 for J, s in
                 ((jacobian_at(fw, p_true, t.data), s) for t, s in zip(traces, sig)))
    corr, se = correlation(fisher)
    combinations(fisher, "the fitted traces")
    # each candidate's information once; then greedy rounds: add the candidate that lowers the
    # largest standard error of ln p (the worst-determined parameter) most, until it is below
    # --target-se or no candidate is left
    info = {}
    for f, phi in CANDIDATES:
        data = (loading_data(f, phi, a.cycles, a.steps_per_cycle) if f > 0
                else creep_data(phi, a.cycles * a.steps_per_cycle))
        J = jacobian_at(fw, p_true, data)
        x = np.asarray(fw({k: jnp.asarray(v) for k, v in p_true.items()}, data))
        name = f"{f:g} Hz, {phi / 1e3:g} kV" if f > 0 else f"creep {CREEP_HOLD:g} s, {phi / 1e3:g} kV"
        info[name] = J.T @ J / (NOISE * np.max(np.abs(x))) ** 2
    print(f"\ndesign (Fisher information of ln p at the truth, noise {100 * NOISE:g} % of each trace's peak; "
          f"{time.perf_counter() - tic:.0f} s): worst correlation and standard errors of ln p")
    print(f"{'experiment':<30} {'worst |corr|':>12} {'pair':>14} " + " ".join(f"{k:>7}" for k in FREE))
    row = lambda name, c, i, j, se_: print(f"{name:<30} {abs(c):12.4f} {i + '-' + j:>14} "  # noqa: E731
                                          + " ".join(f"{v:7.3f}" for v in se_))
    chosen, rows = [], []
    base = " + ".join(f"{f:g}" for f in freqs) + " Hz, 50 kV"
    row(base + " (fitted)", *worst_pair(corr), se)
    rows.append(dict(experiment=base, added=[], worst_corr=worst_pair(corr)[0], se_log=se.tolist()))
    while len(chosen) < len(info) and np.max(se) > a.target_se:
        trials = {}
        for name in info:
            if name not in chosen:
                corr_c, se_c = correlation(fisher + info[name])
                trials[name] = (corr_c, se_c)
                row(f" {'+ ' * (len(chosen) + 1)}{name}", *worst_pair(corr_c), se_c)
        name = min(trials, key=lambda n: float(np.max(trials[n][1])))
        corr_b, se_b = trials[name]
        print(f"  -> add {name}: largest s.e. of ln p {np.max(se):.3g} ({FREE[int(np.argmax(se))]}) -> "
              f"{np.max(se_b):.3g} ({FREE[int(np.argmax(se_b))]}); worst |correlation| "
              f"{abs(worst_pair(corr)[0]):.4f} -> {abs(worst_pair(corr_b)[0]):.4f}")
        chosen.append(name)
        fisher, corr, se = fisher + info[name], corr_b, se_b
        rows.append(dict(experiment=base, added=list(chosen), worst_corr=worst_pair(corr)[0], se_log=se.tolist()))
    print(f"the experiments to add (largest s.e. of ln p below {a.target_se:g}, or every candidate): "
          + ("; ".join(chosen) or "none"))
    if chosen:
        combinations(fisher, "with them")
    out["design"] = rows
    if a.json:
        with open(a.json, "w") as fh:
            json.dump(out, fh, indent=2, default=float)


if __name__ == "__main__":
    main()
