"""The implicit derivative's solve on the uncondensed saddle-point matrix (MKL Pardiso mtype
-2, symmetric indefinite, one host call) against dejax's path (the pressures condensed in XLA,
Pardiso's Cholesky of Kc, one refinement sweep against the exact operator by a second host
call), 12 right-hand sides, tube 4x8x1, Model IV, at the state after 100 steps of R1's loading.
Tried 2026-12-06 and not kept (docs/performance.md).

    REF=0 MATCH=1 python bench/saddle_point_solve.py

REF: Pardiso's iterative refinement steps (iparm[7]); MATCH=1: symmetric weighted matching
and scaling (iparm[10], iparm[12]), without which every pressure pivot is perturbed and the
solution is wrong. Prints both paths' relative errors against a dense LU of the saddle-point
matrix with one refinement step, Pardiso's factorization and solve times, and the current
path's time (XLA and host together, jitted)."""
import os, ctypes, time, jax, jax.numpy as jnp, numpy as np, scipy.sparse as sp
from dejax import bench, integrate as it, model as mdl, linsolve as ls, scenarios
jax.config.update("jax_enable_x64", True)
prob = scenarios.rolled("IV", 30.0, 50e3, shape=(4, 8, 1))
model, scheme = prob.model, prob.scheme()
dt = bench.TUBE_DT
times = it.time_grid(10 / 30.0, dt)[:101]
sol = it.simulate(model, prob.loading, times, prob.output_fn, newton=it.NewtonOptions(tol=bench.TUBE_NEWTON_TOL))
st = sol.final
s = model.structure
t1 = st.t + dt
ctx = it._StepContext(state=st, t1=t1, phi1=prob.loading.phi(t1), u1=jnp.zeros(0) if not model.prescribed_dirs.shape[0] else prob.loading.u(t1),
                      f_ext=mdl.external_force(model), flow=mdl.flow_step(model, st, dt, scheme.flow_update))
z, p = st.q[s.free], st.p
sysm = jax.jit(lambda z, p: it._system(model, scheme, ctx, z, p))(z, p)
n, n_el, n_p = z.size, sysm.kup.shape[0], sysm.kup.shape[1]
print("unknowns", n, "pressures", n_el * n_p)
rng = np.random.default_rng(0)
dru = jnp.asarray(rng.standard_normal((12, n)) * 1e-3)
dg = jnp.asarray(rng.standard_normal((12, n_el, n_p)) * 1e-6)
solver = ls.DenseSolver()
cur = jax.jit(jax.vmap(lambda a, b: it._implicit_solve(model, solver, sysm, a, b)))
dz, dp = cur(dru, dg)
# the saddle-point matrix, dense (reference) and its upper triangle for Pardiso
K = np.asarray(mdl.assemble_dense(model, sysm.Ke))
B = np.asarray(jax.jacfwd(lambda x: it._apply_system(model, sysm, x, jnp.zeros((n_el, n_p)))[1].reshape(-1))(z * 0))
C = np.asarray(jax.scipy.linalg.block_diag(*sysm.kpp))
S = np.block([[K, B.T], [B, C]])
print("symmetry", np.max(np.abs(S - S.T)) / np.max(np.abs(S)))
rhs = -np.concatenate([np.asarray(dru), np.asarray(dg).reshape(12, -1)], 1)
ref = np.linalg.solve(S, rhs.T).T
ref = ref + np.linalg.solve(S, (rhs - ref @ S.T).T).T
x_cur = np.concatenate([np.asarray(dz), np.asarray(dp).reshape(12, -1)], 1)
def err(x): return np.max(np.abs(x - ref)) / np.max(np.abs(ref)), np.max(np.abs(x[:, :n] - ref[:, :n])) / np.max(np.abs(ref[:, :n]))
print("current path: rel. error (all, dz)", err(x_cur))
# Pardiso mtype -2 on the upper triangle (CSR, zero-based)
U = sp.triu(sp.csr_matrix(S)).tocsr(); U.sort_indices()
lib = ls._mkl()
pt = np.zeros(64, np.int64); iparm = np.zeros(64, np.int32)
N = S.shape[0]
ia, ja, a = U.indptr.astype(np.int32), U.indices.astype(np.int32), U.data.astype(np.float64)
def call(phase, b):
    x = np.zeros_like(b); e = ctypes.c_int32(0); i32 = ctypes.POINTER(ctypes.c_int32); f64 = ctypes.POINTER(ctypes.c_double)
    r = lambda v: ctypes.byref(ctypes.c_int32(v))
    lib.pardiso(pt.ctypes.data_as(ctypes.POINTER(ctypes.c_int64)), r(1), r(1), r(-2), r(phase), r(N), a.ctypes.data_as(f64),
                ia.ctypes.data_as(i32), ja.ctypes.data_as(i32), None, r(b.shape[1]), iparm.ctypes.data_as(i32), r(0),
                b.ctypes.data_as(f64), x.ctypes.data_as(f64), ctypes.byref(e))
    assert e.value == 0, (phase, e.value)
    return x
REF, MATCH = int(os.environ.get("REF", 0)), int(os.environ.get("MATCH", 0))
iparm[0] = 1; iparm[1] = 2; iparm[34] = 1; iparm[9] = 13; iparm[7] = REF; iparm[10] = MATCH; iparm[12] = MATCH  # pivot 1e-13, 2 refinement steps, scaling+matching
B1 = np.asfortranarray(rhs.T)
call(11, B1)
tf, ts = [], []
for rep in range(20):
    t = time.perf_counter(); call(22, B1); tf.append(time.perf_counter() - t)
    t = time.perf_counter(); X = call(33, B1); ts.append(time.perf_counter() - t)
print(f"pardiso -2: factor min {min(tf)*1e3:.2f} / median {np.median(tf)*1e3:.2f} ms, 12 solves min {min(ts)*1e3:.2f} / "
      f"median {np.median(ts)*1e3:.2f} ms, perturbed pivots {iparm[13]}, refinement steps {iparm[6]}")
print("saddle-point path: rel. error (all, dz)", err(X.T))
# the current path's time, XLA and host together
tc = []
for rep in range(20):
    t = time.perf_counter(); jax.block_until_ready(cur(dru, dg)); tc.append(time.perf_counter() - t)
print(f"current path (condense, Cholesky, sweep; XLA and host): min {min(tc)*1e3:.2f} / median {np.median(tc)*1e3:.2f} ms")
