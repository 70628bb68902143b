#!/usr/bin/env bash
# Issue 10 point 5: `dejax bench`'s table on a GPU, with the device solver path (the dense
# Cholesky, which `choose_solver("auto")` takes on an accelerator up to 40,000 unknowns:
# the paper's tube R2 included). Run from the repository root; dejax needs no install
# (PYTHONPATH). Each part writes its table (log) and JSON into $OUT (default gpu-bench),
# so a part cut short by its time limit leaves the others' results.
#
#   DEJAX_CACHE_DIR=<folder with bench/*.npz references> bash bench/gpu_table.sh
#
# The accuracy references (dt = 1e-4 s, Newton to 1e-10) are the CPU's, cached by an
# earlier `dejax bench --reference` in $DEJAX_CACHE_DIR/bench; a missing one is computed.
set -u
OUT=${OUT:-gpu-bench}
mkdir -p "$OUT"
export PYTHONPATH="$PWD${PYTHONPATH:+:$PYTHONPATH}" PYTHONUNBUFFERED=1
# the F1 and D1 cases start a child dejax process beside the parent: no process may take
# 75 % of the GPU's memory at start (JAX's default)
export XLA_PYTHON_CLIENT_PREALLOCATE=false

part() {  # part NAME SECONDS ARGS...: one bench run, its own log and JSON
    local name=$1 secs=$2
    shift 2
    echo "=== $name: dejax bench $* (limit ${secs} s)"
    timeout "$secs" python3 -m dejax.cli bench "$@" --json "$OUT/$name.json" 2>&1 | tee "$OUT/$name.log"
    echo "=== $name: exit ${PIPESTATUS[0]}"
}

nvidia-smi -L 2>&1 | tee "$OUT/device.log"
python3 -c "import jax; print('jax', jax.__version__, jax.devices())" 2>&1 | tee -a "$OUT/device.log"
part r1_g1 ${T_R1:-190} --cases R1,G1,G1R --reference
part r2 ${T_R2:-140} --cases R2
part f1 ${T_F1:-90} --cases F1
part r2_first_cycle ${T_R2REF:-70} --cases R2 --max-steps 50 --reference
part d1 ${T_D1:-80} --cases D1
