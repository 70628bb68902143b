"""Cycle measures of periodic (or periodically driven) responses.

The paper's cycle measures (docs/paper-notes.md, "Cycle measures") and a few more, written
in jax.numpy as pure functions so that a fit can differentiate through them; used by
``dejax.outputs`` (per-cycle tables), ``dejax.sweep``, ``fitting.sensitivity`` and
``fitting.diagnose``:

==================  ===========================  ===========================
function            returns (shape)              units
==================  ===========================  ===========================
``x_max``           per-cycle maximum (N,)       those of x
``x_min``           per-cycle minimum (N,)       those of x
``mean``            (x_max + x_min) / 2 (N,)     those of x
``k_c``             mean / mean[1] (N,)          -   (creep parameter)
``loop_area``       per-cycle signed area of     units of x times units of v
                    the x-v loop (N,) or ()
``phase_lag``       lag of x's fundamental       rad, wrapped to (-pi, pi]
                    behind v's ()
``harmonics``       amplitudes of harmonics      those of x
                    1..n (n,)
``fourier``         cos and sin coefficients     those of x
                    (n,), (n,)
``cycle_features``  dict of the above
==================  ===========================  ===========================

``trace_cycle_measures`` (numpy, not differentiable) gives the per-cycle least-squares
measures of a measured trace against its command that the gap diagnosis compares (mean,
first-harmonic amplitude, phase lag, loop area, 2nd/1st harmonic ratio); see its
docstring for how its cycles and measures differ from the ones above.

Conventions
-----------
* ``t`` (n,) in s, strictly increasing; ``x`` and ``v`` (n,) sampled at ``t``.
  Uniform sampling is the normal case but is not required: all integrals use
  the trapezoid rule on the actual sample times.
* The period is given either as ``f`` (Hz) or as ``T = 1/f`` (s), exactly one.
* Cycle k (0-based) is the window ``[t0 + k T, t0 + (k + 1) T)`` with ``t0 =
  t[0]`` unless given. Only *whole* cycles count: cycle k is used when the
  samples cover it, ``t[-1] >= t0 + (k + 1) T`` (to within 1e-9 T), so sample
  up to and including the end of the last cycle (``np.linspace(0, N T, N m +
  1)``). Trailing samples of an incomplete cycle are ignored. N is the number
  of whole cycles; ``n_cycles`` may cap it.
* ``t``, ``f``/``T``, ``t0`` and ``n_cycles`` are *data*: they must be
  concrete (numpy or Python numbers, not jax tracers), because they fix which
  samples belong to which cycle. ``x`` and ``v`` may be traced: every
  function is differentiable in them (``jax.grad``, ``jax.jacfwd``) and can
  run under ``jax.jit`` with ``t`` closed over. For batches use ``jax.vmap``
  over ``x``.

Accuracy: the exact per-cycle extrema are extrema of the samples, low by
O(b (pi f dt)^2 / 2) for a sinusoid of amplitude b; the trapezoid integrals
(loop area, Fourier projections) are second order in ``f dt`` and exact to
round-off for band-limited signals sampled evenly with an integer number of
samples per period.

Smooth extrema
--------------
``soft=False`` (default) takes the exact per-cycle max/min of the samples.
Its gradient exists almost everywhere (it flows to the arg-max sample) but
jumps when the arg-max sample changes, which can upset gradient-based fits on
coarse sampling. ``soft=True`` replaces it by the Boltzmann (softmax-weighted)
mean ``sum x_i w_i / sum w_i``, ``w_i = exp((x_i - max) / temperature)`` over
the cycle's samples: smooth, always between the cycle's min and max, and equal
to the max as ``temperature -> 0``. ``temperature`` is in the units of x;
the default is ``0.03 * std(x)`` over the whole cycles (about 1 % of the
peak-to-peak range of a sinusoid), which depends smoothly on x and is
differentiated along with it. In a fit, pass a fixed ``temperature`` so that
the measure does not change definition from one iterate to the next. The soft
max is biased low: for a smooth (locally quadratic) peak resolved by the
sampling the bias is about ``temperature / 2`` (about 1 % of the half range
of a sinusoid with the default); choose a smaller temperature for accuracy, a
larger one for smoothness.

Drift
-----
``fourier``, ``harmonics`` and ``phase_lag`` fit, by least squares over the
whole cycles, ``x(t) ~ c0 + c1 (t - t_mid) + sum_k (a_k cos(2 pi k f t) + b_k
sin(2 pi k f t))``. With ``detrend=True`` (default) the linear term absorbs a
steady drift (creep), so a drifting sinusoid gives its true amplitude and
phase; with ``detrend=False`` only the constant is fitted, which is the plain
Fourier projection over whole cycles.
"""
from __future__ import annotations

from dataclasses import dataclass

import jax
import jax.numpy as jnp
import numpy as np

__all__ = [
    "Cycles",
    "cycles",
    "x_max",
    "x_min",
    "mean",
    "amplitude",
    "k_c",
    "loop_area",
    "fourier",
    "harmonics",
    "phase_lag",
    "cycle_features",
    "trace_cycle_ids",
    "trace_cycle_measures",
    "TRACE_MEASURES",
]

_TOL = 1e-9  # relative (to T) tolerance on cycle boundaries


# ---------------------------------------------------------------------------
# cycle bookkeeping (numpy, concrete)
# ---------------------------------------------------------------------------


@dataclass(frozen=True, eq=False)
class Cycles:
    """Assignment of samples to whole cycles (all numpy, concrete).

    Attributes:
      t: (n,) sample times (s).
      t0: start of cycle 0 (s).
      T: period (s).
      n: number of whole cycles N used.
      ids: (n,) cycle index of each sample; N for samples outside the whole
        cycles (before t0 or in the trailing incomplete cycle).
      first, last: (N,) index of each cycle's first and last sample.
    """

    t: np.ndarray
    t0: float
    T: float
    n: int
    ids: np.ndarray
    first: np.ndarray
    last: np.ndarray

    @property
    def end(self) -> float:
        """End time of the last whole cycle (s)."""
        return self.t0 + self.n * self.T


def _concrete(a, name):
    try:
        return np.asarray(a, dtype=float)
    except (jax.errors.TracerArrayConversionError, jax.errors.ConcretizationTypeError, TypeError) as e:
        raise TypeError(
            f"features: {name} must be concrete (numpy / Python numbers), not a traced "
            f"jax value: it decides which samples form each cycle. Close over it instead "
            f"of passing it as a jit/grad argument."
        ) from e


def _period(f, T) -> float:
    if (f is None) == (T is None):
        raise ValueError("features: give exactly one of f (frequency, Hz) or T (period, s)")
    if T is None:
        f = float(_concrete(f, "f"))
        if not (np.isfinite(f) and f > 0):
            raise ValueError(f"features: frequency f = {f} Hz must be finite and > 0")
        return 1.0 / f
    T = float(_concrete(T, "T"))
    if not (np.isfinite(T) and T > 0):
        raise ValueError(f"features: period T = {T} s must be finite and > 0")
    return T


def cycles(t, f=None, *, T=None, t0=None, n_cycles=None, min_cycles: int = 1) -> Cycles:
    """Split the samples ``t`` (n,) into whole cycles of period ``T = 1/f``.

    Raises ValueError if ``t`` is not 1-D and strictly increasing, or if fewer
    than ``min_cycles`` whole cycles fit in ``[t0, t[-1]]``.
    """
    t = _concrete(t, "t")
    if t.ndim != 1 or t.size < 2:
        raise ValueError(f"features: t must be 1-D with at least 2 samples, got shape {t.shape}")
    if not np.all(np.isfinite(t)):
        raise ValueError("features: t contains NaN or inf")
    if np.any(np.diff(t) <= 0):
        i = int(np.argmax(np.diff(t) <= 0))
        raise ValueError(f"features: t must increase strictly; t[{i + 1}] = {t[i + 1]} <= t[{i}] = {t[i]}")
    T = _period(f, T)
    t0 = float(t[0]) if t0 is None else float(_concrete(t0, "t0"))
    if t0 < t[0] - _TOL * T:
        raise ValueError(f"features: t0 = {t0} s is before the first sample t[0] = {t[0]} s")
    n_whole = int(np.floor((t[-1] - t0) / T + _TOL))
    if n_cycles is not None:
        if int(n_cycles) > n_whole:
            raise ValueError(
                f"features: n_cycles = {n_cycles} requested but only {n_whole} whole cycles of "
                f"T = {T:g} s fit in [{t0:g}, {t[-1]:g}] s"
            )
        n_whole = int(n_cycles)
    if n_whole < max(min_cycles, 1):
        raise ValueError(
            f"features: need at least {max(min_cycles, 1)} whole cycle(s) of T = {T:g} s, but "
            f"[{t0:g}, {t[-1]:g}] s holds {n_whole}; sample up to and including the end of the last cycle"
        )
    k = np.floor((t - t0) / T + _TOL).astype(np.int64)
    ids = np.where((k >= 0) & (k < n_whole), k, n_whole)
    cyc = np.arange(n_whole)
    first = np.searchsorted(k, cyc, side="left")  # k is non-decreasing
    last = np.searchsorted(k, cyc, side="right") - 1
    few = np.nonzero(last - first < 1)[0]
    if few.size:
        c = int(few[0])
        raise ValueError(
            f"features: cycle {c} holds {last[c] - first[c] + 1} sample(s); the sampling (dt ~ "
            f"{np.median(np.diff(t)):g} s) is too coarse for T = {T:g} s"
        )
    return Cycles(t=t, t0=t0, T=T, n=n_whole, ids=ids, first=first, last=last)


def _as_x(x, n, name="x"):
    x = jnp.asarray(x)
    if x.ndim != 1 or x.shape[0] != n:
        raise ValueError(f"features: {name} must have shape ({n},) like t, got {x.shape}")
    if not jnp.issubdtype(x.dtype, jnp.floating):
        x = x.astype(float)
    return x


# ---------------------------------------------------------------------------
# extrema
# ---------------------------------------------------------------------------


@jax.jit
def _segmax_kernel(x, ids, dummy):
    # dummy: (N + 1,) zeros fixing the number of segments statically
    return jax.ops.segment_max(x, ids, num_segments=dummy.shape[0])[:-1]


def _segment_max(x, c: Cycles):
    return _segmax_kernel(x, jnp.asarray(c.ids), jnp.zeros(c.n + 1))


@jax.jit
def _soft_segmax_kernel(x, ids, used, tau, dummy):
    n1 = dummy.shape[0]
    xs = jax.lax.stop_gradient(x)
    if tau is None:  # 0.03 std: smooth in x, ~1e-2 of the peak-to-peak range of a sinusoid
        n_used = jnp.sum(used)
        mu = jnp.sum(jnp.where(used, x, 0.0)) / n_used
        var = jnp.sum(jnp.where(used, (x - mu) ** 2, 0.0)) / n_used
        pos = var > 0
        tau = jnp.where(pos, 0.03 * jnp.sqrt(jnp.where(pos, var, 1.0)), 1.0)
    m = jax.ops.segment_max(xs, ids, num_segments=n1)
    m = jnp.where(jnp.isfinite(m), m, 0.0)[ids]
    w = jnp.exp((x - m) / tau)
    num = jax.ops.segment_sum(w * x, ids, num_segments=n1)[:-1]
    den = jax.ops.segment_sum(w, ids, num_segments=n1)[:-1]
    return num / den


def _soft_segment_max(x, c: Cycles, temperature):
    tau = None if temperature is None else jnp.asarray(temperature, dtype=x.dtype)
    return _soft_segmax_kernel(x, jnp.asarray(c.ids), jnp.asarray(c.ids < c.n), tau, jnp.zeros(c.n + 1))


def x_max(t, x, f=None, *, T=None, t0=None, n_cycles=None, soft=False, temperature=None):
    """Per-cycle maximum of ``x``: (N,) array in the units of x.

    ``soft=True`` gives the smooth Boltzmann-weighted maximum (module docstring);
    ``temperature`` is then in the units of x.
    """
    c = cycles(t, f, T=T, t0=t0, n_cycles=n_cycles)
    x = _as_x(x, c.t.size)
    if soft:
        return _soft_segment_max(x, c, temperature)
    return _segment_max(x, c)


def x_min(t, x, f=None, *, T=None, t0=None, n_cycles=None, soft=False, temperature=None):
    """Per-cycle minimum of ``x``: (N,) array in the units of x (see ``x_max``)."""
    return -x_max(t, -jnp.asarray(x), f, T=T, t0=t0, n_cycles=n_cycles, soft=soft, temperature=temperature)


def mean(t, x, f=None, *, T=None, t0=None, n_cycles=None, soft=False, temperature=None):
    """Per-cycle mean position ``xbar = (x_max + x_min) / 2``: (N,), units of x.

    This is the paper's mean (the midpoint of the cycle's range), not the time
    average.
    """
    kw = dict(T=T, t0=t0, n_cycles=n_cycles, soft=soft, temperature=temperature)
    return 0.5 * (x_max(t, x, f, **kw) + x_min(t, x, f, **kw))


def amplitude(t, x, f=None, *, T=None, t0=None, n_cycles=None, soft=False, temperature=None):
    """Per-cycle half range ``(x_max - x_min) / 2``: (N,), units of x."""
    kw = dict(T=T, t0=t0, n_cycles=n_cycles, soft=soft, temperature=temperature)
    return 0.5 * (x_max(t, x, f, **kw) - x_min(t, x, f, **kw))


def k_c(t, x, f=None, *, T=None, t0=None, n_cycles=None, soft=False, temperature=None):
    """Creep parameter per cycle ``k_c = xbar / xbar_0``: (N,), dimensionless.

    ``xbar_0`` is the mean of the *second* cycle (index 1), so ``k_c[1] == 1``;
    needs at least 2 whole cycles. Undefined (inf/NaN) when ``xbar_0 == 0``.
    """
    c = cycles(t, f, T=T, t0=t0, n_cycles=n_cycles, min_cycles=2)
    m = mean(c.t, x, T=c.T, t0=c.t0, n_cycles=c.n, soft=soft, temperature=temperature)
    return m / m[1]


# ---------------------------------------------------------------------------
# loop area
# ---------------------------------------------------------------------------


def loop_area(x, v, t=None, f=None, *, T=None, t0=None, n_cycles=None):
    """Signed area of the hysteresis loop traced in the (v, x) plane.

    Args:
      x, v: (n,) arrays, e.g. displacement (m) and voltage (V) or field (V/m).
      t, f (or T): when given, the area of each whole cycle is returned, (N,);
        when ``t`` is None the whole arrays form one loop and a scalar is
        returned.

    The area is the closed line integral ``A = loop-integral of v dx``
    evaluated by the trapezoid (shoelace) rule over consecutive samples of the
    cycle, closing each cycle's polygon from its last sample back to its first.
    Units: those of v times those of x (V m for voltage and displacement).
    Sign: positive when x lags v (a dissipative loop, traversed clockwise when
    x is plotted against v); for ``x = b sin(w t - delta)``, ``v = V sin(w t)``
    it is ``pi b V sin(delta)``.
    """
    x = jnp.asarray(x)
    v = jnp.asarray(v)
    if t is None:
        if f is not None or T is not None:
            raise ValueError("loop_area: f/T given without t; pass t to split into cycles")
        if x.ndim != 1 or x.shape != v.shape or x.shape[0] < 3:
            raise ValueError(f"loop_area: x and v must be 1-D of equal length >= 3, got {x.shape}, {v.shape}")
        xc = jnp.concatenate([x, x[:1]])
        vc = jnp.concatenate([v, v[:1]])
        return jnp.sum(0.5 * (vc[1:] + vc[:-1]) * (xc[1:] - xc[:-1]))
    c = cycles(t, f, T=T, t0=t0, n_cycles=n_cycles)
    n = c.t.size
    x = _as_x(x, n)
    v = _as_x(v, n, "v")
    same = (c.ids[:-1] == c.ids[1:]) & (c.ids[:-1] < c.n)
    seg = np.where(same, c.ids[:-1], c.n)
    return _loop_kernel(x, v, jnp.asarray(seg), jnp.asarray(c.first), jnp.asarray(c.last), jnp.zeros(c.n + 1))


@jax.jit
def _loop_kernel(x, v, seg, fi, la, dummy):
    terms = 0.5 * (v[1:] + v[:-1]) * (x[1:] - x[:-1])
    inner = jax.ops.segment_sum(terms, seg, num_segments=dummy.shape[0])[:-1]
    closing = 0.5 * (v[la] + v[fi]) * (x[fi] - x[la])
    return inner + closing


# ---------------------------------------------------------------------------
# Fourier analysis over whole cycles
# ---------------------------------------------------------------------------


def _window_weights(t: np.ndarray, a: float, b: float) -> np.ndarray:
    """Weights w (n,) with sum w_i g_i = integral over [a, b] of the piecewise
    linear interpolant of samples g_i at t_i (a, b may fall between samples)."""
    t0, t1 = t[:-1], t[1:]
    h = t1 - t0
    lo = np.clip(a, t0, t1)
    hi = np.clip(b, t0, t1)
    w_left = ((t1 - lo) ** 2 - (t1 - hi) ** 2) / (2 * h)
    w_right = ((hi - t0) ** 2 - (lo - t0) ** 2) / (2 * h)
    w = np.zeros_like(t)
    np.add.at(w, np.arange(t.size - 1), w_left)
    np.add.at(w, np.arange(1, t.size), w_right)
    return w


def _projector(c: Cycles, n_harm: int, detrend: bool) -> np.ndarray:
    """Matrix P (n_basis, n) mapping samples to least-squares coefficients of
    [1, (t - t_mid)/T (if detrend), cos 1..n, sin 1..n] over the whole cycles."""
    t = c.t
    w = _window_weights(t, c.t0, c.end)
    omega = 2 * np.pi / c.T
    rows = [np.ones_like(t)]
    if detrend:
        rows.append((t - 0.5 * (c.t0 + c.end)) / c.T)
    k = np.arange(1, n_harm + 1)[:, None]
    rows.extend(np.cos(k * omega * t))
    rows.extend(np.sin(k * omega * t))
    B = np.vstack(rows)
    G = (B * w) @ B.T
    if np.count_nonzero(w) < B.shape[0] or np.linalg.matrix_rank(G) < B.shape[0]:
        raise ValueError(f"features: {n_harm} harmonic(s){' and a drift' if detrend else ''} need at least "
                         f"{B.shape[0]} samples over the whole cycles, spread over the period; got "
                         f"{np.count_nonzero(w)}: sample more finely (e.g. more steps per cycle)")
    return np.linalg.solve(G, B * w)


def fourier(t, x, f=None, n: int = 1, *, T=None, t0=None, n_cycles=None, detrend=True):
    """Cosine and sine coefficients of harmonics 1..n of ``x`` over whole cycles.

    Returns ``(a, b)``, each (n,) in the units of x, such that
    ``x(t) ~ offset [+ drift] + sum_k a_k cos(2 pi k f t) + b_k sin(2 pi k f t)``
    in the least-squares sense over the whole cycles (the phase reference is
    t = 0, not t0). See the module docstring for ``detrend``.
    """
    n = int(n)
    if n < 1:
        raise ValueError(f"fourier: n = {n} harmonics; need n >= 1")
    c = cycles(t, f, T=T, t0=t0, n_cycles=n_cycles)
    x = _as_x(x, c.t.size)
    P = _projector(c, n, detrend)
    off = 2 if detrend else 1
    # the sine and cosine rows of P
    return _fourier_kernel(jnp.asarray(P[off : off + n]), jnp.asarray(P[off + n : off + 2 * n]), x)


@jax.jit
def _fourier_kernel(Pc, Ps, x):
    return Pc @ x, Ps @ x


@jax.jit
def _safe_hypot(a, b):
    r2 = a * a + b * b
    pos = r2 > 0
    return jnp.where(pos, jnp.sqrt(jnp.where(pos, r2, 1.0)), 0.0)


def harmonics(t, x, f=None, n: int = 3, *, T=None, t0=None, n_cycles=None, detrend=True):
    """Amplitudes of the first ``n`` harmonics of ``x`` over whole cycles.

    Returns (n,) in the units of x: ``sqrt(a_k^2 + b_k^2)`` for k = 1..n (see
    ``fourier``); a pure sinusoid ``b sin(2 pi f t - delta)`` gives (b, 0, ...).
    """
    a, b = fourier(t, x, f, n, T=T, t0=t0, n_cycles=n_cycles, detrend=detrend)
    return _safe_hypot(a, b)


def phase_lag(t, x, v, f=None, *, T=None, t0=None, n_cycles=None, detrend=True):
    """Phase lag (rad) of x's fundamental behind v's, over whole cycles.

    With ``x ~ X sin(2 pi f t + theta_x)`` and ``v ~ V sin(2 pi f t + theta_v)``
    (least-squares fundamentals, see ``fourier``) returns ``theta_v - theta_x``
    wrapped to (-pi, pi]: positive when x lags v. For ``x = b sin(2 pi f t -
    delta)`` and ``v = sin(2 pi f t)`` it is ``delta``. Scalar.
    """
    kw = dict(T=T, t0=t0, n_cycles=n_cycles, detrend=detrend)
    ax, bx = fourier(t, x, f, 1, **kw)
    av, bv = fourier(t, v, f, 1, **kw)
    return _lag_kernel(ax[0], bx[0], av[0], bv[0])


@jax.jit
def _lag_kernel(ax, bx, av, bv):
    # angle of (bv + i av) / (bx + i ax) = theta_v - theta_x
    return jnp.arctan2(av * bx - bv * ax, bv * bx + av * ax)


# ---------------------------------------------------------------------------
# everything at once
# ---------------------------------------------------------------------------


def cycle_features(
    t,
    x,
    v=None,
    f=None,
    *,
    T=None,
    t0=None,
    n_cycles=None,
    n_harmonics: int = 3,
    soft=False,
    temperature=None,
    detrend=True,
) -> dict:
    """All cycle measures of ``x`` (and of the x-v loop when ``v`` is given).

    Returns a dict of jax arrays (N = number of whole cycles):

    * ``x_max``, ``x_min``, ``mean``, ``amplitude``: (N,), units of x.
    * ``k_c``: (N,), present when N >= 2.
    * ``harmonics``: (n_harmonics,), units of x.
    * with ``v``: ``loop_area`` (N,) (units x * v), ``phase_lag`` () (rad),
      ``v_harmonics`` (n_harmonics,) (units of v).

    plus ``n_cycles`` (int) and ``period`` (float, s).
    """
    c = cycles(t, f, T=T, t0=t0, n_cycles=n_cycles)
    kw = dict(T=c.T, t0=c.t0, n_cycles=c.n)
    ext = dict(kw, soft=soft, temperature=temperature)
    hi = x_max(c.t, x, **ext)
    lo = x_min(c.t, x, **ext)
    out = {
        "n_cycles": c.n,
        "period": c.T,
        "x_max": hi,
        "x_min": lo,
        "mean": 0.5 * (hi + lo),
        "amplitude": 0.5 * (hi - lo),
    }
    if c.n >= 2:
        out["k_c"] = out["mean"] / out["mean"][1]
    out["harmonics"] = harmonics(c.t, x, n=n_harmonics, detrend=detrend, **kw)
    if v is not None:
        out["loop_area"] = loop_area(x, v, c.t, **kw)
        out["phase_lag"] = phase_lag(c.t, x, v, detrend=detrend, **kw)
        out["v_harmonics"] = harmonics(c.t, v, n=n_harmonics, detrend=detrend, **kw)
    return out


# ---------------------------------------------------------------------------
# per-cycle least-squares measures of a driven trace (numpy)
# ---------------------------------------------------------------------------

TRACE_MEASURES = ("mean", "amplitude", "phase_lag", "loop_area", "h2")
"""The measures of ``trace_cycle_measures``, in order."""


def trace_cycle_ids(t, freq) -> np.ndarray:
    """Cycle index (n,) of each sample of a trace driven at ``freq`` (Hz): cycle k holds
    ``t[0] + k/freq <= t < t[0] + (k + 1)/freq``, and the closing sample(s) after the last
    complete cycle join it. Without a frequency (None or 0) every sample is in cycle 0."""
    t = np.asarray(t, dtype=float)
    if not freq:
        return np.zeros(len(t), dtype=int)
    ids = np.floor((t - t[0]) * freq + 1e-9).astype(int)
    n_complete = max(int(np.floor((t[-1] - t[0]) * freq + 1e-9)), 1)
    return np.minimum(ids, n_complete - 1)


def trace_cycle_measures(t, y, u, freq) -> dict:
    """Per complete cycle of ``y`` (n,) driven by the command ``u`` (n,, V) at ``freq`` (Hz):
    name -> (n_cycles,) arrays of

    * ``mean``: the constant of a least-squares fit of 1, cos, sin of harmonics 1 and 2 over
      the cycle (units of y; the time average, unlike ``mean`` above);
    * ``amplitude``: the first harmonic's amplitude of that fit (units of y);
    * ``phase_lag``: lag of y's first harmonic behind u's (rad, wrapped to [-pi, pi),
      positive when y lags);
    * ``loop_area``: the closed integral of y du over the cycle's samples (units y V; the
      opposite orientation to ``loop_area`` above, which integrates v dx);
    * ``h2``: |2nd harmonic| / |1st harmonic| of y.

    Cycles as ``trace_cycle_ids``; a cycle with fewer than 8 samples or spanning less than
    0.9 of a period is left out. Empty arrays without a frequency."""
    t = np.asarray(t, dtype=float)
    y = np.asarray(y, dtype=float)
    u = np.asarray(u, dtype=float)
    out = {k: [] for k in TRACE_MEASURES}
    if not freq:
        return {k: np.zeros(0) for k in out}
    ids = trace_cycle_ids(t, freq)
    w = 2 * np.pi * freq
    for c in range(int(ids.max()) + 1):
        m = ids == c
        if m.sum() < 8 or (t[m][-1] - t[m][0]) < 0.9 / freq:
            continue
        tt = t[m]
        A = np.stack([np.ones_like(tt), np.cos(w * tt), np.sin(w * tt), np.cos(2 * w * tt), np.sin(2 * w * tt)], 1)
        cy, *_ = np.linalg.lstsq(A, y[m], rcond=None)
        cu, *_ = np.linalg.lstsq(A, u[m], rcond=None)
        h1y, h1u = complex(cy[1], -cy[2]), complex(cu[1], -cu[2])
        out["mean"].append(cy[0])
        out["amplitude"].append(abs(h1y))
        lag = np.angle(h1u) - np.angle(h1y)
        out["phase_lag"].append(float((lag + np.pi) % (2 * np.pi) - np.pi))
        um, ym = np.append(u[m], u[m][0]), np.append(y[m], y[m][0])  # closed polygon
        out["loop_area"].append(float(np.sum(0.5 * (ym[1:] + ym[:-1]) * np.diff(um))))
        out["h2"].append(abs(complex(cy[3], -cy[4])) / max(abs(h1y), 1e-300))
    return {k: np.asarray(v, dtype=float) for k, v in out.items()}
