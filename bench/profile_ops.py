"""Where a whole run's time goes, by XLA operation (issue 10, point 2): R1's forward run or
G1's derivative run, traced with ``jax.profiler`` and the operations' durations summed.

    python bench/profile_ops.py --case G1 [--steps 100] [--top 25]
    python bench/profile_ops.py --case N1 --by-path 4

Cases (tube 4x8x1, Model IV, 50 kV, 30 Hz, dt = 5e-4 s as ``dejax bench``'s R1 and G1):
``R1`` the forward run (step cut-back allowed), ``G1`` ``jax.jacfwd`` of the last-cycle
mean x_P with respect to the 12 parameters of G1 (user's grid), ``G1R`` the same by one
reverse pass. Printed: the total operation time (summed over XLA's threads, so it can
exceed the wall time), the time per operation kind (the HLO name without its number:
``multiply_reduce_fusion``, ``lu``, ...) and per individual operation. ``N1``: the bench's
one-iteration full-Newton step of R2 (a fresh factorization per call), per call instead of
per step. Control flow (``while``, ``cond``, ``call``) is listed apart and left out of the
total: its span contains the operations of its body, which are counted themselves. With
``--hlo FILE`` the optimized HLO text, to look an operation up by name (its shapes and the
jaxpr path in its metadata); with ``--by-source`` the time grouped by that path
(``by_source``), with ``--by-path K`` by its first K components. After one untraced call
(compilation).
"""
from __future__ import annotations

import argparse
import collections
import glob
import re
import tempfile

import jax

from dejax import bench
from dejax import integrate as it


CONTROL = ("while", "cond", "call", "conditional")


def op_times(f, args, calls: int = 1):
    """{(kind, name): seconds per call} of the XLA operations of ``f(*args)`` (jitted)."""
    jax.block_until_ready(f(*args))
    folder = tempfile.mkdtemp(prefix="dejax-trace-")
    jax.profiler.start_trace(folder)
    for _ in range(calls):
        out = f(*args)
    jax.block_until_ready(out)
    jax.profiler.stop_trace()
    (path,) = glob.glob(folder + "/**/*.xplane.pb", recursive=True)
    totals = collections.Counter()
    for plane in jax.profiler.ProfileData.from_file(path).planes:
        for line in plane.lines:
            if not line.name.startswith("tf_XLA") or "Eigen" not in line.name:
                continue  # XLA's compute threads only
            for ev in line.events:
                if "ThunkExecutor" in ev.name:
                    continue  # the executor's own span, not an operation
                if ev.name.startswith("$"):
                    continue  # Python frames inside a host callback: its pure_callback span has them
                totals[ev.name] += ev.duration_ns * 1e-9 / calls
    return totals


def op_names(hlo: str) -> dict:
    """{operation name: its op_name metadata (the JAX source path)} of optimized HLO text."""
    meta = {}
    for m in re.finditer(r'^\s*(?:ROOT\s+)?%?([\w.\-]+) = [^\n]*?metadata=\{[^}]*op_name="([^"]*)"', hlo, re.M):
        meta.setdefault(m.group(1), m.group(2))
    return meta


def by_source(totals, hlo: str) -> collections.Counter:
    """{source: seconds}: each operation's time under the JAX source its HLO metadata names,
    cut to the part inside a step (after the step's last ``branch_1_fun/``, the cut-back
    branch that runs it) and to its first component (two for ``while``/``vmap()``); "outside
    the step" for the rest. A heuristic for reading a profile, not an exact attribution."""
    meta = op_names(hlo)
    out = collections.Counter()
    for name, s in totals.items():
        path = meta.get(name)
        if path is None:
            key = "(no metadata)"
        elif "branch_1_fun/" in path:
            parts = path.rsplit("branch_1_fun/", 1)[1].split("/")
            key = "/".join(parts[:2]) if parts[0] in ("while", "vmap()") else parts[0]
        else:
            key = "(outside the step) " + path.rsplit("/", 1)[-1]
        out[re.sub(r"\d+", "#", key)] += s
    return out


def by_path(totals, hlo: str, depth: int) -> collections.Counter:
    """{path: seconds}: each operation's time under the first ``depth`` components of its
    HLO op_name below the jitted function's own (numbers replaced by #)."""
    meta = op_names(hlo)
    out = collections.Counter()
    for name, s in totals.items():
        out[re.sub(r"\d+", "#", "/".join(meta.get(name, "(no metadata)").split("/")[1:1 + depth]))] += s
    return out


class _FreshFactorizations:
    """f(*args) with the sparse solver's cached factorizations dropped first (N1's call)."""

    def __init__(self, f):
        self.f = f

    def __call__(self, *args):
        from dejax import linsolve

        linsolve.clear_factorizations()
        return self.f(*args)

    def lower(self, *args):
        return self.f.lower(*args)


def n1_function():
    _, _, one, s0, fac0 = bench.n1_step()
    return _FreshFactorizations(one), (s0, fac0)


def case_function(case: str, steps: int, dt: float = 5e-4):
    if case == "N1":
        return n1_function()
    mean_last_cycle, theta0 = bench.g1_objective(steps, dt)
    f = {"R1": lambda th: mean_last_cycle(th, it.StepControl()), "G1": jax.jacfwd(mean_last_cycle),
         "G1R": jax.grad(mean_last_cycle)}[case]
    return jax.jit(f), (theta0,)


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("--case", choices=("R1", "G1", "G1R", "N1"), default="G1")
    ap.add_argument("--steps", type=int, default=100)
    ap.add_argument("--top", type=int, default=25)
    ap.add_argument("--hlo", default=None, help="write the optimized HLO text here")
    ap.add_argument("--by-path", type=int, default=0,
                    help="also group the operations by the first K components of their op_name (N1: 4)")
    ap.add_argument("--by-source", action="store_true",
                    help="also group the operations by the JAX source they came from (HLO op_name metadata)")
    a = ap.parse_args()
    f, args = case_function(a.case, a.steps)
    if a.case == "N1":
        a.steps = 1  # per call
    totals = op_times(f, args, calls=3 if a.case == "N1" else 1)
    kinds, control = collections.Counter(), collections.Counter()
    for name, s in totals.items():
        kind = re.sub(r"\.\d+$", "", name)
        (control if kind in CONTROL else kinds)[kind] += s
    totals = collections.Counter({k: v for k, v in totals.items() if re.sub(r"\.\d+$", "", k) not in CONTROL})
    total = sum(totals.values())
    per = "call" if a.case == "N1" else "step"
    print(f"{a.case}, {a.steps} {per}s: {total:.2f} s of XLA operation time ({1e3 * total / a.steps:.1f} ms per {per})")
    print("control flow (spans include their bodies' operations): "
          + ", ".join(f"{k} {1e3 * v / a.steps:.1f} ms/step" for k, v in control.most_common()))
    print("by kind:")
    for k, s in kinds.most_common(a.top):
        print(f"  {1e3 * s / a.steps:9.2f} ms/step  {100 * s / total:5.1f} %  {k}")
    print("by operation:")
    for k, s in totals.most_common(a.top):
        print(f"  {1e3 * s / a.steps:9.2f} ms/step  {100 * s / total:5.1f} %  {k}")
    if a.hlo or a.by_source or a.by_path:
        hlo = f.lower(*args).compile().as_text()
    if a.by_path:
        print(f"by the first {a.by_path} components of the op_name:")
        for k, s in by_path(totals, hlo, a.by_path).most_common(a.top):
            print(f"  {1e3 * s / a.steps:9.2f} ms/step  {100 * s / total:5.1f} %  {k}")
    if a.by_source:
        print("by source (the op_name's first component inside the step: an einsum, jit(mapped) = the "
              "per-point material law, jvp(...) its tangent lanes, while/body the Newton loop):")
        for k, s in by_source(totals, hlo).most_common(a.top):
            print(f"  {1e3 * s / a.steps:9.2f} ms/step  {100 * s / total:5.1f} %  {k}")
    if a.hlo:
        with open(a.hlo, "w") as fh:
            fh.write(hlo)
        print(f"optimized HLO written to {a.hlo}")


if __name__ == "__main__":
    main()
