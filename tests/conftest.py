"""Shared pytest configuration: a ``slow`` marker for tests whose compilation takes minutes.

Run them with ``pytest --runslow`` (or DEJAX_RUNSLOW=1)."""
import os

# Tests run short simulations, where XLA's compile time dominates: skip its backend
# optimisation passes (measured about 27 % less CPU time for the same tests; importing
# dejax adds its own XLA:CPU options, ``dejax.CPU_XLA_FLAGS``).
os.environ.setdefault("XLA_FLAGS", "--xla_backend_optimization_level=0")
# One persistent compilation cache for the session's workers: a program compiled by one
# test file is loaded, not compiled again, by the others (DEJAX_COMPILE_CACHE=0: off).
os.environ.setdefault("DEJAX_CACHE_DIR", os.path.join(os.path.dirname(os.path.dirname(os.path.abspath(__file__))),
                                                      ".pytest_cache", "dejax-jax"))

import pytest  # noqa: E402


def pytest_addoption(parser):
    parser.addoption("--runslow", action="store_true", default=False, help="also run tests marked slow")


def pytest_configure(config):
    config.addinivalue_line("markers", "slow: takes minutes (compilation); skipped unless --runslow")
    from dejax import compile_cache

    if not compile_cache.disabled_by_env():
        compile_cache.enable()


# The test files that take longest (compilation-bound; measured 20-80 s of test time each
# on 2 cores with a cold compilation cache), longest first. They are handed to the workers
# first (``--dist loadfile`` follows the collection order), so that the short files fill the
# end and both workers finish together.
LONGEST_FIRST = ("test_cli_e2e.py", "test_integrate.py", "test_integrate_robust.py", "test_verification_models.py",
                 "test_diagnose.py", "test_linsolve.py", "test_cli_ux.py", "test_scenarios.py",
                 "test_verification_block_effects.py", "test_model.py", "test_forward.py", "test_sweep.py",
                 "test_verification_cases.py", "test_cli.py", "test_material.py", "test_effects.py")


def _file_rank(item):
    name = os.path.basename(str(item.fspath))
    return LONGEST_FIRST.index(name) if name in LONGEST_FIRST else len(LONGEST_FIRST)


def pytest_collection_modifyitems(config, items):
    items.sort(key=_file_rank)  # stable: the order within a file is kept
    if config.getoption("--runslow") or os.environ.get("DEJAX_RUNSLOW"):
        return
    skip = pytest.mark.skip(reason="slow: run with --runslow")
    for item in items:
        if "slow" in item.keywords:
            item.add_marker(skip)
