"""Sim-to-real gap diagnosis: where the gap lies, which unmodelled effect explains it, how far it shrinks.

Inputs: a baseline forward model (a dejax ``Problem`` whose material carries two dormant
viscous units, see ``fitting.effects``) and measured traces with role "fit" or "holdout".

(a) WHERE: baseline residuals broken down per trace/condition, per cycle, loading vs
    unloading (sign of d phi_command/dt), transient (first cycle) vs steady state, and
    per cycle feature (mean, amplitude, phase lag to the command, loop area in the
    (command, output) plane, 2nd/1st harmonic ratio).
(b) WHICH: every candidate effect is fitted on the fit traces (its parameters only, the
    baseline held; start = off values or the effect's start values, bounded
    Levenberg-Marquardt on normalised parameters with a forward-difference Jacobian, so
    the one compiled ``simulate`` is reused), then ranked: significant effects first
    (Delta BIC < -``bic_threshold``), within them by the holdout RMS. Gauss-Newton
    standard errors s^2 (J^T J)^-1 at the optimum.
(c) HOW FAR: RMS and "gap" = sqrt(max(RMS^2 - sigma^2, 0)) before/after, on fit and
    holdout, overall and per feature.

Noise level sigma: given, or estimated from the measured traces by 4th differences
(sigma^2 = mean((Delta^4 y)^2)/70, unbiased for white noise when the signal is smooth
over 5 samples). Verdict "no significant gap" when the baseline's fit residual passes
the chi-square test RMS^2/sigma^2 <= 1 + z sqrt(2/n) (z = 4) and no candidate lowers
BIC by more than ``bic_threshold`` (10: "very strong" evidence).

The written report (markdown, JSON, figures): ``fitting.report``; the verb: ``fitting.cli``.
"""
from __future__ import annotations

import dataclasses
import math
import time as _time
from typing import Mapping, Sequence

import equinox as eqx
import jax.numpy as jnp
import numpy as np

from dejax import cycles
from dejax import integrate as it
from dejax import loads

from . import effects as fx

__all__ = ["TraceData", "Forward", "CandidateResult", "Diagnosis", "diagnose", "estimate_noise",
           "breakdown", "forward_from_experiment"]


@dataclasses.dataclass
class TraceData:
    """One measured trace: t (s), y (output units), base (commanded voltage history t -> V),
    role "fit"/"holdout", conditions (dict), freq (Hz or None)."""

    name: str
    t: np.ndarray
    y: np.ndarray
    base: object
    role: str = "fit"
    conditions: dict = dataclasses.field(default_factory=dict)
    freq: float | None = None

    @property
    def command(self) -> np.ndarray:
        return np.asarray(self.base(jnp.asarray(self.t)))


class Forward:
    """Baseline + effects -> predicted outputs, reusing one compiled simulate.

    problem: a dejax Problem built with ``effects.augment_material(material)``;
    output: the output name (e.g. "lateral_stretch"); transform: optional y -> y' applied
    to the raw output before the sensor (e.g. stretch -> displacement).

    Newton: full Newton by default (``reuse=False``): with a lagged voltage the modified
    (reused-factorisation) Newton stalled on the block (NEWTON_FAILED at t ~ 0.2 s for
    tau = 10-16 ms), full Newton converges in ~4 iterations. A failed run is scored with
    output 1e3 after the failure (a huge residual), not raised."""

    def __init__(self, problem, output: str = "lateral_stretch", rho_inf: float | None = None,
                 newton: it.NewtonOptions = it.NewtonOptions(tol=1e-8, max_iter=60, reuse=False), face_area: float | None = None,
                 pad_to: int | None = None, transform=None):
        self.problem = problem
        self.pieces0 = fx.make_pieces(problem, face_area)
        self.output = output
        self.scheme = it.GeneralizedAlpha(problem.rho_inf if rho_inf is None else rho_inf)
        self.newton = newton
        self.pad_to = pad_to
        self.transform = transform
        self._cache: dict = {}
        self.n_sims = 0

    @staticmethod
    def _key(effects: Mapping, trace: TraceData):
        items = []
        for name in sorted(effects):
            if fx.get(name).kind == "model":
                items.append((name, tuple(sorted((k, round(float(v), 15)) for k, v in effects[name].items()))))
        return (trace.name, tuple(items))

    def raw(self, effects: Mapping, trace: TraceData) -> np.ndarray:
        """Model output (before the sensor transform) on the trace's time grid."""
        key = self._key(effects, trace)
        if key in self._cache:
            return self._cache[key]
        model_fx = {k: v for k, v in effects.items() if fx.get(k).kind == "model"}
        p = fx.apply_effects(self.pieces0, model_fx)
        loading = eqx.tree_at(lambda l: l.voltages[0].base, p.loading, trace.base)
        n = len(trace.t) - 1
        pad = max(self.pad_to or n, n)
        sol = it.simulate(p.model, loading, trace.t, self.problem.output_fn, self.scheme, self.newton, pad_to=pad,
                          control=None)  # fixed steps, as the fits (experiment.FIT_STEP_CONTROL)
        self.n_sims += 1
        y = np.asarray(sol.outputs[self.output], dtype=float)
        if not sol.ok:  # failed run: report a huge residual rather than crash the ranking
            y = np.where(np.isfinite(y), y, 0.0)
            y[int(sol.fail_step) + 1:] = 1e3
        if self.transform is not None:
            y = np.asarray(self.transform(y))
        if len(self._cache) > 2000:
            self._cache.clear()
        self._cache[key] = y
        return y

    def predict(self, effects: Mapping, trace: TraceData) -> np.ndarray:
        y = self.raw(effects, trace)
        sensor_fx = {k: v for k, v in effects.items() if fx.get(k).kind == "sensor"}
        if not sensor_fx:
            return y
        s = fx.apply_effects(self.pieces0, sensor_fx).sensor
        return np.asarray(s(jnp.asarray(trace.t), jnp.asarray(y)))


# ----------------------------------------------------------------------------- noise, breakdown


def estimate_noise(traces: Sequence[TraceData]) -> float:
    """Pooled white-noise sigma from 4th differences: Var(Delta^4 e) = 70 sigma^2."""
    num, den = 0.0, 0
    for tr in traces:
        d = np.diff(np.asarray(tr.y, dtype=float), 4)
        num += float(np.sum(d ** 2))
        den += d.size
    return math.sqrt(num / (70.0 * max(den, 1)))


def breakdown(traces: Sequence[TraceData], preds: Sequence[np.ndarray]) -> dict:
    """Residual (model - measured) broken down by trace/condition, cycle, loading/unloading,
    transient/steady state, and features (model - measured, per cycle and mean)."""
    res = {"traces": [], "features": {}}
    feat_acc: dict = {}
    for tr, yp in zip(traces, preds):
        r = np.asarray(yp) - tr.y
        ids = cycles.trace_cycle_ids(tr.t, tr.freq)
        du = np.gradient(tr.command, tr.t)
        load = du > 0
        entry = {"name": tr.name, "role": tr.role, "conditions": dict(tr.conditions), "rms": _rms(r),
                 "mean_residual": float(np.mean(r)),
                 "per_cycle_rms": [_rms(r[ids == c]) for c in range(int(ids.max()) + 1)],
                 "loading_rms": _rms(r[load]), "unloading_rms": _rms(r[~load]),
                 "transient_rms": _rms(r[ids == 0]), "steady_rms": _rms(r[ids > 0]) if np.any(ids > 0) else None}
        fm = cycles.trace_cycle_measures(tr.t, tr.y, tr.command, tr.freq)
        fp = cycles.trace_cycle_measures(tr.t, yp, tr.command, tr.freq)
        entry["features"] = {k: {"measured": fm[k].tolist(), "model": fp[k].tolist(),
                                 "gap": (fp[k] - fm[k]).tolist()} for k in fm}
        res["traces"].append(entry)
        for k in fm:
            feat_acc.setdefault(k, []).append((fp[k] - fm[k], fm[k]))
    for k, lst in feat_acc.items():
        gaps = np.concatenate([g for g, _ in lst]) if lst else np.zeros(0)
        meas = np.concatenate([m for _, m in lst]) if lst else np.zeros(0)
        scale = float(np.mean(np.abs(meas))) if meas.size else 0.0
        res["features"][k] = {"rms_gap": _rms(gaps), "mean_gap": float(np.mean(gaps)) if gaps.size else 0.0,
                              "relative": _rms(gaps) / scale if scale > 0 else None}
    return res


def _rms(x) -> float:
    x = np.asarray(x, dtype=float)
    return float(np.sqrt(np.mean(x ** 2))) if x.size else 0.0


# ----------------------------------------------------------------------------- fitting one effect


def _to_z(p: fx.Param, x):
    lo, hi = p.bounds
    if p.scale == "log":
        return (math.log(x) - math.log(lo)) / (math.log(hi) - math.log(lo))
    return (x - lo) / (hi - lo)


def _from_z(p: fx.Param, z):
    lo, hi = p.bounds
    z = min(max(z, 0.0), 1.0)
    if p.scale == "log":
        return math.exp(math.log(lo) + z * (math.log(hi) - math.log(lo)))
    return lo + z * (hi - lo)


def _dx_dz(p: fx.Param, x):
    lo, hi = p.bounds
    return x * (math.log(hi) - math.log(lo)) if p.scale == "log" else (hi - lo)


@dataclasses.dataclass
class CandidateResult:
    name: str
    values: dict
    stderr: dict
    k: int
    sse_fit: float
    rms_fit: float
    rms_holdout: float | None
    aic: float
    bic: float
    d_aic: float
    d_bic: float
    n_sims: int
    seconds: float
    significant: bool = False

    def as_dict(self):
        return dataclasses.asdict(self)


def _residuals(fwd: Forward, effects: Mapping, traces: Sequence[TraceData]) -> np.ndarray:
    return np.concatenate([fwd.predict(effects, tr) - tr.y for tr in traces])


def fit_effects(fwd: Forward, names: Sequence[str], traces: Sequence[TraceData], start: Mapping | None = None,
                max_iter: int = 8, fixed: Mapping | None = None, rtol: float = 1e-4):
    """Bounded Levenberg-Marquardt over the parameters of the effects ``names`` (normalised
    to [0, 1] in lin or log scale), others in ``fixed`` held. Returns (values, stderr, sse, J)."""
    fixed = dict(fixed or {})
    start = dict(start or {})
    plist = [(n, p) for n in names for p in fx.get(n).params]

    def vals_of(z):
        out = {n: dict(fixed.get(n, fx.get(n).off())) for n in names}
        for (n, p), zi in zip(plist, z):
            out[n][p.name] = _from_z(p, zi)
        return {**fixed, **out}

    def resid(z):
        return _residuals(fwd, vals_of(z), traces)

    # start: off values and the effects' start values; keep the better
    cands = []
    for src in ("off", "start"):
        z = np.array([_to_z(p, min(max(start.get(n, {}).get(p.name, getattr(p, src)), p.bounds[0]), p.bounds[1])
                                if not (p.scale == "log" and getattr(p, src) <= 0) else 0.5)
                      for n, p in plist], dtype=float)
        cands.append(z)
    best_z, best_r = None, None
    for z in cands:
        if best_z is not None and np.allclose(z, best_z):
            continue
        r = resid(z)
        if best_r is None or r @ r < best_r @ best_r:
            best_z, best_r = z, r
    z, r = best_z, best_r
    sse = float(r @ r)
    lam = 1e-2
    h = 1e-3
    J = None
    for _ in range(max_iter):
        J = np.empty((r.size, z.size))
        for j in range(z.size):
            hj = h if z[j] + h <= 1.0 else -h
            zz = z.copy()
            zz[j] += hj
            J[:, j] = (resid(zz) - r) / hj
        g = J.T @ r
        A = J.T @ J
        improved = False
        for _ls in range(4):
            dz = -np.linalg.solve(A + lam * np.diag(np.diag(A) + 1e-12 * (np.trace(A) + 1e-300)), g)
            zn = np.clip(z + dz, 0.0, 1.0)
            if np.allclose(zn, z, atol=1e-7):
                break
            rn = resid(zn)
            ssen = float(rn @ rn)
            if ssen < sse:
                improved = True
                rel = (sse - ssen) / max(sse, 1e-300)
                z, r, sse = zn, rn, ssen
                lam = max(lam / 5, 1e-6)
                break
            lam *= 8
        if not improved or rel < rtol:
            break
    # Gauss-Newton covariance in natural units
    vals = vals_of(z)
    stderr = {}
    if J is not None:
        n, k = r.size, z.size
        s2 = sse / max(n - k, 1)
        D = np.array([_dx_dz(p, vals[nm][p.name]) for nm, p in plist])
        Jx = J / D[None, :]
        try:
            cov = s2 * np.linalg.pinv(Jx.T @ Jx)
            sd = np.sqrt(np.maximum(np.diag(cov), 0.0))
        except np.linalg.LinAlgError:
            sd = np.full(k, np.nan)
        for (nm, p), s in zip(plist, sd):
            stderr.setdefault(nm, {})[p.name] = float(s)
    return vals, stderr, sse, J


# ----------------------------------------------------------------------------- diagnosis


@dataclasses.dataclass
class Diagnosis:
    verdict: str
    best: str | None
    noise: float
    chi2_ratio: float
    chi2_limit: float
    baseline: dict
    ranking: list
    breakdown_before: dict
    breakdown_after: dict | None
    shrinkage: dict | None
    n_fit: int
    seconds: float
    preds: dict = dataclasses.field(default_factory=dict, repr=False)

    def table(self) -> str:
        lines = [f"{'rank':>4} {'effect':<20} {'k':>2} {'dBIC':>9} {'dAIC':>9} {'RMS fit':>10} {'RMS hold':>10} "
                 f"{'sig':>3}  parameters (+- 1 sd)"]
        for i, c in enumerate(self.ranking):
            pv = ", ".join(f"{n}.{k}={v:.4g}+-{c['stderr'].get(n, {}).get(k, float('nan')):.2g}"
                           for n, d in c["values"].items() for k, v in d.items())
            hold = f"{c['rms_holdout']:.3e}" if c["rms_holdout"] is not None else "-"
            lines.append(f"{i + 1:>4} {c['name']:<20} {c['k']:>2} {c['d_bic']:>9.1f} {c['d_aic']:>9.1f} "
                         f"{c['rms_fit']:>10.3e} {hold:>10} {'*' if c['significant'] else '':>3}  {pv}")
        b = self.baseline
        hold = f"{b['rms_holdout']:.3e}" if b["rms_holdout"] is not None else "-"
        lines.insert(1, f"{'-':>4} {'baseline':<20} {0:>2} {0.0:>9.1f} {0.0:>9.1f} {b['rms_fit']:>10.3e} {hold:>10}")
        return "\n".join(lines)

    def as_dict(self):
        d = dataclasses.asdict(self)
        d.pop("preds")
        return d


def _ic(sse, n, k):
    ll = n * math.log(max(sse, 1e-300) / n)
    return ll + 2 * k, ll + k * math.log(n)


def _gap(rms, sigma):
    return math.sqrt(max(rms ** 2 - sigma ** 2, 0.0))


def diagnose(fwd: Forward, traces: Sequence[TraceData], candidates: Sequence[str] | None = None,
             noise: float | None = None, bic_threshold: float = 10.0, z: float = 4.0, max_iter: int = 8,
             start: Mapping | None = None, verbose: bool = False) -> Diagnosis:
    """Run (a)-(c) of the module docstring. ``candidates``: effect names (default: all)."""
    t0 = _time.time()
    fit = [tr for tr in traces if tr.role == "fit"]
    hold = [tr for tr in traces if tr.role != "fit"]
    if not fit:
        raise ValueError("diagnose: no trace with role 'fit'")
    candidates = list(candidates or fx.names())
    sigma = estimate_noise(traces) if noise is None else float(noise)
    n = int(sum(len(tr.t) for tr in fit))

    if verbose:
        print(f"[diagnose] baseline: simulating {len(traces)} trace(s) (the first call compiles the simulation) ...",
              flush=True)
    base_pred = {tr.name: fwd.predict({}, tr) for tr in traces}
    if verbose:
        print(f"[diagnose] baseline done in {_time.time() - t0:.1f} s; fitting {len(candidates)} candidate effect(s)",
              flush=True)
    r0 = np.concatenate([base_pred[tr.name] - tr.y for tr in fit])
    sse0 = float(r0 @ r0)
    aic0, bic0 = _ic(sse0, n, 0)
    rms_h0 = _rms(np.concatenate([base_pred[tr.name] - tr.y for tr in hold])) if hold else None
    baseline = {"sse_fit": sse0, "rms_fit": _rms(r0), "rms_holdout": rms_h0, "aic": aic0, "bic": bic0}
    chi = (sse0 / n) / sigma ** 2 if sigma > 0 else float("inf")
    chi_lim = 1.0 + z * math.sqrt(2.0 / n)
    before = breakdown(traces, [base_pred[tr.name] for tr in traces])

    results = []
    for name in candidates:
        ts = _time.time()
        s0 = fwd.n_sims
        vals, sd, sse, _ = fit_effects(fwd, [name], fit, start=start, max_iter=max_iter)
        k = fx.get(name).n_params
        aic, bic = _ic(sse, n, k)
        rh = _rms(np.concatenate([fwd.predict(vals, tr) - tr.y for tr in hold])) if hold else None
        c = CandidateResult(name, vals, sd, k, sse, math.sqrt(sse / n), rh, aic, bic, aic - aic0, bic - bic0,
                            fwd.n_sims - s0, _time.time() - ts)
        c.significant = c.d_bic < -bic_threshold
        results.append(c)
        if verbose:
            rh_text = "-" if rh is None else f"{rh:.3e}"
            print(f"  [{len(results)}/{len(candidates)}] {name:<20} dBIC={c.d_bic:9.1f} rms_fit={c.rms_fit:.3e} "
                  f"rms_hold={rh_text} ({c.seconds:.1f} s)", flush=True)

    def key(c):
        return (not c.significant, c.rms_holdout if c.rms_holdout is not None else c.rms_fit, c.bic)

    results.sort(key=key)
    best = results[0] if results and results[0].significant else None
    if best is not None:
        verdict = f"gap explained by '{best.name}'"
    elif chi > chi_lim:
        verdict = "significant gap, not explained by the candidate effects"
    else:
        verdict = "no significant gap"

    after = shrink = None
    preds = {"baseline": base_pred}
    if best is not None:
        bp = {tr.name: fwd.predict(best.values, tr) for tr in traces}
        preds[best.name] = bp
        after = breakdown(traces, [bp[tr.name] for tr in traces])
        shrink = {}
        for role, rms0, rms1 in (("fit", baseline["rms_fit"], best.rms_fit), ("holdout", rms_h0, best.rms_holdout)):
            if rms0 is None:
                continue
            g0, g1 = _gap(rms0, sigma), _gap(rms1, sigma)
            shrink[role] = {"rms_before": rms0, "rms_after": rms1, "gap_before": g0, "gap_after": g1,
                            "gap_shrinkage": 1.0 - g1 / g0 if g0 > 0 else None}
        shrink["features"] = {}
        for f, d0 in before["features"].items():
            g0, g1 = d0["rms_gap"], after["features"][f]["rms_gap"]
            shrink["features"][f] = {"gap_before": g0, "gap_after": g1, "shrinkage": 1.0 - g1 / g0 if g0 > 0 else None}
    return Diagnosis(verdict, best.name if best else None, sigma, chi, chi_lim, baseline,
                     [c.as_dict() for c in results], before, after, shrink, n, _time.time() - t0, preds)


# ----------------------------------------------------------------------------- experiment files


def _history(tr) -> object:
    """The commanded voltage history of a trace: its loading table, else its voltage column."""
    if tr.loading is not None and "voltage" not in tr.channels:
        return loads.from_spec(tr.loading)
    if "voltage" in tr.channels:
        return loads.PiecewiseLinear(tr.time, tr.channels["voltage"])
    raise ValueError(f"trace '{tr.name}': no voltage column and no loading table")


def forward_from_experiment(exp) -> tuple[Forward, list[TraceData]]:
    """Forward model and TraceData of a block-scenario Experiment. Response channel: ``stretch``
    (lateral stretch) or ``displacement`` ((stretch - 1) L, m)."""
    from dejax import scenarios as sc
    from dejax.material import Material

    if exp.scenario != "block":
        raise NotImplementedError(f"diagnose supports the 'block' scenario for now, not '{exp.scenario}'")
    g = exp.geometry
    L = float(g.get("L", g.get("lx", 1e-3)))
    mat = fx.augment_material(Material(**exp.material_kwargs()))
    traces = []
    channel = None
    for tr in exp.traces:
        ch = "stretch" if "stretch" in tr.channels else "displacement" if "displacement" in tr.channels else None
        if ch is None:
            raise ValueError(f"trace '{tr.name}': needs a 'stretch' or 'displacement' channel for the block")
        if channel not in (None, ch):
            raise ValueError("all traces must carry the same response channel")
        channel = ch
        traces.append(TraceData(tr.name, np.asarray(tr.time, dtype=float), np.asarray(tr[ch], dtype=float),
                                _history(tr), tr.role, dict(tr.conditions), tr.frequency))
    pad = max(len(t.t) for t in traces) - 1
    prob = sc.block(L=L, shape=tuple(g.get("mesh", (1, 1, 1))), material=mat,
                    gauss_order=int(exp.solver.get("gauss_order", 3)), damping=float(exp.solver.get("damping", 0.0)),
                    voltage=traces[0].base)
    transform = None if channel == "stretch" else (lambda y, L=L: (y - 1.0) * L)
    fwd = Forward(prob, "lateral_stretch", rho_inf=exp.solver.get("rho_inf"), pad_to=pad, transform=transform)
    return fwd, traces


# ----------------------------------------------------------------------------- synthetic studies


def block_forward(material=None, L: float = 1e-3, pad_to: int | None = None) -> Forward:
    """Forward model of the 1-element DE block (paper Sec. 4 material by default) with two
    dormant viscous units, output lateral_stretch."""
    from dejax import scenarios as sc

    mat = fx.augment_material(sc.block_material() if material is None else material)
    prob = sc.block(L=L, material=mat, voltage=loads.Sine(12e3, 1.0))
    return Forward(prob, "lateral_stretch", pad_to=pad_to)


def synthetic_traces(fwd: Forward, conditions, truth: Mapping, noise: float, seed: int = 0,
                     n_cycles: float = 3.0, samples_per_cycle: int = 40) -> list[TraceData]:
    """Traces of the block made with the effects ``truth`` ({name: values}) plus white noise.
    conditions: sequence of (name, role, phi_max V, freq Hz)."""
    rng = np.random.default_rng(seed)
    out = []
    for name, role, phi, f in conditions:
        n = int(round(n_cycles * samples_per_cycle))
        t = np.linspace(0.0, n_cycles / f, n + 1)
        tr = TraceData(name, t, np.zeros_like(t), loads.Sine(phi, f), role, {"phi_max": phi, "freq": f}, f)
        y = fwd.predict(truth, tr)
        tr.y = y + noise * rng.standard_normal(y.shape)
        out.append(tr)
    return out
