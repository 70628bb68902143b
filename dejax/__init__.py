"""dejax: differentiable hyper-viscoelastic simulation of dielectric elastomer actuators.

Importing dejax enables float64 in JAX (the bulk-to-shear ratio K/mu ~ 1e5 needs it).
"""
import jax

jax.config.update("jax_enable_x64", True)

__version__ = "0.1.0"
