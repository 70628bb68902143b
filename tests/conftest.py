"""Shared pytest configuration: a ``slow`` marker for tests whose compilation takes minutes.

Run them with ``pytest --runslow`` (or DEJAX_RUNSLOW=1)."""
import os

# Tests run short simulations, where XLA's compile time dominates: skip its backend
# optimisation passes (measured about 27 % less CPU time for the same tests).
os.environ.setdefault("XLA_FLAGS", "--xla_backend_optimization_level=0")

import pytest  # noqa: E402


def pytest_addoption(parser):
    parser.addoption("--runslow", action="store_true", default=False, help="also run tests marked slow")


def pytest_configure(config):
    config.addinivalue_line("markers", "slow: takes minutes (compilation); skipped unless --runslow")


def pytest_collection_modifyitems(config, items):
    if config.getoption("--runslow") or os.environ.get("DEJAX_RUNSLOW"):
        return
    skip = pytest.mark.skip(reason="slow: run with --runslow")
    for item in items:
        if "slow" in item.keywords:
            item.add_marker(skip)
