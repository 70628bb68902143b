"""Parameter sweeps of the rolled DEA (paper Figs. 15-16, 20-23): per-case cycle features.

Every case of a sweep has the same mesh topology, the same number of steps per cycle
and the same number of cycles, so all cases share ONE compiled stepper:

* ``method="sequential"``: one compiled ``simulate`` reused case after case (the model's
  arrays are rebuilt for each case and grafted onto the first case's static structure;
  the time grid has a fixed length, dt = 1/(f * steps_per_cycle)).
* ``method="vmap"``: the cases are stacked and run in one ``jax.vmap``-ed, jitted
  simulate. With more than one device in ``jax.devices()`` (several GPUs; on a CPU,
  ``XLA_FLAGS=--xla_force_host_platform_device_count=N`` set before JAX starts) the
  case axis is sharded over all of them (``NamedSharding`` over a one-axis mesh
  ``"case"``): the cases are padded with copies of the last one to a multiple of the
  device count, each device runs its share, and the padding is dropped from the rows.
  Every loop of the vmapped stepper (Newton, line search, cut-back) runs until the
  slowest case of the whole batch is done: the devices exchange one boolean per
  iteration (a scalar all-reduce), no case data. On emulated CPU devices keep the
  XLA:CPU thread pool larger than the device count (``PJRT_NPROC``; see
  ``_warn_cpu_pool``). Caveat: under vmap the Newton solver's ``lax.cond``
  (refactor or reuse) executes both branches, so each vmapped step does a full
  tangent + factorization: on one CPU it is slower than the sequential path; it pays
  off on accelerators / several devices.

Sweepable parameters: h, r, L (m), freq (Hz), phi_max (V); ``field_const=True`` scales
phi_max with h to keep phi_max/h fixed (paper Fig. 20).
"""
from __future__ import annotations

import itertools
import os
import time
import warnings

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np

from . import integrate as it
from . import scenarios

SWEEPABLE = ("h", "r", "L", "freq", "phi_max")


class SweepOutputs(eqx.Module):
    """x_P (m), voltage (V), field = voltage x |Grad unit potential| (V/m, traced, not static:
    cases with different h share the compiled code)."""

    node: int = eqx.field(static=True, converter=int)

    def __call__(self, model, loading, state):
        i = 12 * self.node
        phi = loading.phi(state.t)[0]
        return {"x_P": state.q[i] - model.q0[i], "voltage": phi,
                "field": phi * jnp.linalg.norm(model.field_dirs[0, 0, 0])}


def cases_from_grid(grid: dict, base: dict | None = None, field_const: bool = False) -> list[dict]:
    """Cartesian product of ``grid`` (name -> values) over ``base`` parameters."""
    base = dict(dict(model="IV", freq=30.0, phi_max=50e3, h=2e-3, r=2e-3, L=8e-3), **(base or {}))
    for k in grid:
        if k not in SWEEPABLE:
            raise ValueError(f"cannot sweep {k!r}; sweepable: {SWEEPABLE}")
    names = list(grid)
    out = []
    for vals in itertools.product(*(list(grid[k]) for k in names)):
        c = dict(base, **dict(zip(names, (float(v) for v in vals))))
        if field_const and "h" in grid:
            c["phi_max"] = base["phi_max"] * c["h"] / base["h"]
        out.append(c)
    return out


def _problem(case, shape, point="P"):
    return scenarios.rolled(case.get("model", "IV"), freq=case["freq"], phi_max=case["phi_max"], h=case["h"],
                            r=case["r"], L=case["L"], shape=shape, point=point)


_TREEDEFS: dict = {}


def _build(cases, shape, point="P"):
    """(problems, models, loadings) sharing one static structure per (shape, point, material
    model), cached for the session: later sweeps reuse the compiled stepper."""
    probs = [_problem(c, shape, point) for c in cases]
    key = (tuple(shape), point, str(cases[0].get("model", "IV")))
    if key not in _TREEDEFS:
        _TREEDEFS[key] = (jax.tree_util.tree_structure(probs[0].model), jax.tree_util.tree_structure(probs[0].loading))
    mdef, ldef = _TREEDEFS[key]
    models = [jax.tree_util.tree_unflatten(mdef, jax.tree_util.tree_leaves(p.model)) for p in probs]
    loadings = [jax.tree_util.tree_unflatten(ldef, jax.tree_util.tree_leaves(p.loading)) for p in probs]
    return probs, models, loadings


def _grid(freq, n_cycles, steps_per_cycle):
    return np.linspace(0.0, n_cycles / float(freq), n_cycles * steps_per_cycle + 1)


def simulate_case(case, shape=(1, 4, 1), n_cycles=2, steps_per_cycle=40, t_stop=None, rho_inf=0.8,
                  newton=it.NewtonOptions(), point="P"):
    """One case on the shared compiled stepper; returns (Problem, Solution).

    ``t_stop`` (s, <= n_cycles/freq): stop there (the scan is padded to the full length, so
    the same compiled code runs); sol.final is then the state at t_stop (e.g. a peak)."""
    probs, models, loadings = _build([case], shape, point)
    g = _grid(case["freq"], n_cycles, steps_per_cycle)
    n_full = g.size - 1
    if t_stop is not None:
        g = g[: int(np.argmin(np.abs(g - t_stop))) + 1]
    sol = it.simulate(models[0], loadings[0], g, SweepOutputs(probs[0].extras["P"]), it.GeneralizedAlpha(rho_inf),
                      newton, pad_to=n_full)
    return probs[0], sol


def case_features(t, outputs, freq) -> dict:
    """Scalar features of one case: last-cycle x_max, x_min, mean, amplitude, loop area,
    k_c of the last cycle (NaN with < 2 cycles)."""
    from .outputs import cycle_table

    tab = cycle_table(np.asarray(t), np.asarray(outputs["x_P"]), np.asarray(outputs["field"]), freq)
    if len(tab["cycle"]) == 0:
        return {}
    return {"x_max": float(tab["x_max"][-1]), "x_min": float(tab["x_min"][-1]), "mean": float(tab["mean"][-1]),
            "amplitude": float(tab["amplitude"][-1]), "loop_area": float(tab["loop_area"][-1]),
            "k_c": float(tab["k_c"][-1]), "n_cycles": int(len(tab["cycle"]))}


def _cpu_pool_size() -> int:
    """Threads of XLA:CPU's intra-op pool: ``PJRT_NPROC``, else ``NPROC``, else the CPU count."""
    for name in ("PJRT_NPROC", "NPROC"):
        try:
            return int(os.environ[name])
        except (KeyError, ValueError):
            pass
    return os.cpu_count() or 1


def _warn_cpu_pool(devices) -> None:
    """Emulated CPU devices run their programs on ONE intra-op thread pool, and the batched
    LAPACK LU (jaxlib's ``lapack_dgetrf_ffi``) waits on that pool for its sub-tasks: with
    as many devices as pool threads, every thread can be waiting at once (seen with 2
    devices on 2 cores: the run hangs). A larger pool (PJRT_NPROC) avoids it."""
    if devices[0].platform == "cpu" and len(devices) >= _cpu_pool_size():
        warnings.warn(f"{len(devices)} CPU devices on an XLA:CPU thread pool of {_cpu_pool_size()} threads: the "
                      f"batched LU can deadlock; set PJRT_NPROC={len(devices) + 2} (or more) before JAX starts",
                      RuntimeWarning, stacklevel=3)


@eqx.filter_jit
def _batched(M, Lg, G, out_fn, scheme, newton):
    """vmap of simulate over stacked models, loadings and time grids (one compilation per
    structure / output / scheme / Newton options / batch size)."""

    def one(m, l, g):
        sol = it.simulate(m, l, g, out_fn, scheme, newton)
        return sol.outputs, sol.status

    return jax.vmap(one)(M, Lg, G)


def run_sweep(cases, shape=(1, 4, 1), n_cycles=2, steps_per_cycle=40, method="sequential", rho_inf=0.8,
              newton=it.NewtonOptions(), point="P", keep_series=False, progress=None):
    """Run every case; returns (rows, info).

    rows: list of dicts (the case's parameters + case_features + ok/status; with
    keep_series the time series under "series"). info: method, n_devices (the devices
    the cases ran on: 1 for sequential; for vmap, those holding the batch's results),
    n_batch (cases per compiled call: 1, or for vmap the cases padded to a multiple of
    the device count), wall_s (total, compilation included), first_s (wall time of the
    first case / batch call).
    progress: optional ``progress(cases_done, n_cases, wall_s, ok)`` after each case
    (sequential) or once after the batch (vmap).
    """
    cases = [dict(c) for c in cases]
    probs, models, loadings = _build(cases, shape, point)
    out_fn = SweepOutputs(probs[0].extras["P"])
    scheme = it.GeneralizedAlpha(rho_inf)
    grids = [_grid(c["freq"], n_cycles, steps_per_cycle) for c in cases]
    tic = time.perf_counter()
    results = []
    first_s = None
    n_used, n_batch = 1, 1  # devices the cases ran on, cases per compiled call (sequential: one on one)
    if method == "sequential":
        for m, l, g in zip(models, loadings, grids):
            t0 = time.perf_counter()
            sol = it.simulate(m, l, g, out_fn, scheme, newton, pad_to=g.size - 1)
            jax.block_until_ready(sol.outputs["x_P"])
            first_s = first_s if first_s is not None else time.perf_counter() - t0
            results.append((np.asarray(sol.time), {k: np.asarray(v) for k, v in sol.outputs.items()},
                            int(sol.status)))
            if progress is not None:
                progress(len(results), len(cases), time.perf_counter() - tic, results[-1][2] == 0)
    elif method == "vmap":
        devices = jax.devices()
        n = len(cases)
        idx = list(range(n)) + [n - 1] * ((-n) % len(devices))  # pad with copies of the last case
        n_batch = len(idx)
        stack = lambda xs: jax.tree_util.tree_map(lambda *a: jnp.stack(a), *[xs[i] for i in idx])
        M, Lg, G = stack(models), stack(loadings), jnp.asarray(np.stack([grids[i] for i in idx]))
        if len(devices) > 1:
            from jax.sharding import Mesh, NamedSharding, PartitionSpec

            # every stacked leaf split along its leading (case) axis, n_batch / n_devices per device
            shard = NamedSharding(Mesh(np.array(devices), ("case",)), PartitionSpec("case"))
            _warn_cpu_pool(devices)
            put = lambda a: jax.device_put(a, shard) if hasattr(a, "shape") and a.ndim >= 1 else a
            M, Lg, G = (jax.tree_util.tree_map(put, x) for x in (M, Lg, G))

        t0 = time.perf_counter()
        outs, status = _batched(M, Lg, G, out_fn, scheme, newton)
        jax.block_until_ready(outs["x_P"])
        first_s = time.perf_counter() - t0
        n_used = len(outs["x_P"].sharding.device_set)  # the devices the batch's results lie on
        outs, status = {k: np.asarray(v) for k, v in outs.items()}, np.asarray(status)  # one transfer each
        for i in range(n):
            results.append((grids[i], {k: v[i] for k, v in outs.items()}, int(status[i])))
        if progress is not None:
            progress(n, n, time.perf_counter() - tic, all(r[2] == 0 for r in results))
    else:
        raise ValueError(f"method must be 'sequential' or 'vmap', got {method!r}")
    wall = time.perf_counter() - tic
    rows = []
    for c, (t, o, st) in zip(cases, results):
        row = dict(c, ok=st == 0, status=st)
        if st == 0:
            row.update(case_features(t, o, c["freq"]))
        if keep_series:
            row["series"] = {"time": t, **o}
        rows.append(row)
    info = dict(method=method, n_devices=n_used, n_cases=len(cases), n_batch=n_batch, wall_s=wall, first_s=first_s,
                shape=list(shape), n_cycles=n_cycles, steps_per_cycle=steps_per_cycle)
    return rows, info
