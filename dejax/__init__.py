"""dejax: differentiable hyper-viscoelastic simulation of dielectric elastomer actuators.

Importing dejax enables float64 in JAX (the bulk-to-shear ratio K/mu ~ 1e5 needs it) and,
with the jaxlib releases it was measured on (``CPU_XLA_FLAGS_JAXLIB``) and unless
``XLA_FLAGS`` already names the option, sets two XLA:CPU options (``CPU_XLA_FLAGS``):

* YNNPACK library fusions restricted to matrix products: on the per-Gauss-point 3 x 3
  algebra of the material its elementwise and reduction fusions are slower than XLA's own
  loops (tube 4x8x1: the element system 17.2 -> 6.0 ms, a residual 1.36 -> 0.98 ms, a time
  step 9.4 -> 6.4 ms; tube 12x20x4: the element system 669 -> 371 ms;
  ``python bench/xla_cpu_options.py``);
* fusions emitted as plain loops rather than through XLA:CPU's MLIR fusion emitters
  (``--xla_cpu_use_fusion_emitters=false``): ``dejax bench --cases R1``, alternated,
  compile 8.6-11.0 -> 7.3-8.3 s, run 8.4-11.5 -> 7.6-9.9 s, peak memory 900-960 -> 530 MB;
  the block's simulation at the test suite's optimization level 0: backend compilation
  16 -> 7 s, its run 2.5 -> 1.8 s.

Other releases are left alone: XLA aborts the process on an option it does not know. The
flags take effect only if dejax is imported before JAX's CPU backend starts (JAX reads
``XLA_FLAGS`` then).
"""
import importlib.metadata
import os

CPU_XLA_FLAGS = ("--xla_cpu_experimental_ynn_fusion_type=LIBRARY_FUSION_TYPE_DOT", "--xla_cpu_use_fusion_emitters=false")
CPU_XLA_FLAGS_JAXLIB = ("0.10.",)  # jaxlib version prefixes that know (and were measured with) these flags


def _set_xla_flags(flags=CPU_XLA_FLAGS) -> None:
    try:
        jaxlib = importlib.metadata.version("jaxlib")
    except importlib.metadata.PackageNotFoundError:
        return
    if not jaxlib.startswith(CPU_XLA_FLAGS_JAXLIB):
        return
    current = os.environ.get("XLA_FLAGS", "")
    added = [f for f in flags if f.split("=", 1)[0] not in current]
    if added:
        os.environ["XLA_FLAGS"] = " ".join([current, *added]).strip()


_set_xla_flags()

import jax  # noqa: E402

jax.config.update("jax_enable_x64", True)

__version__ = "0.1.0"
