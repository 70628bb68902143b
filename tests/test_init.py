"""Import-time settings of dejax (dejax/__init__.py): float64 and the XLA:CPU options."""
import importlib.metadata
import os
import subprocess
import sys

import pytest

import dejax


def _child(code, env_xla=None):
    env = {k: v for k, v in os.environ.items() if k != "XLA_FLAGS"}
    if env_xla is not None:
        env["XLA_FLAGS"] = env_xla
    p = subprocess.run([sys.executable, "-c", code], env=env, capture_output=True, text=True, timeout=120)
    assert p.returncode == 0, p.stderr[-2000:]
    return p.stdout.strip()


RUN = ("import os, dejax, jax, jax.numpy as jnp; x = jax.jit(lambda a: (a * a).sum(-1))(jnp.ones((4, 3)));"
       "print(os.environ.get('XLA_FLAGS', ''), x.dtype, float(x[0]))")


def test_importing_dejax_sets_the_option_xla_accepts_and_float64():
    """A fresh process: the options are set on the jaxlib releases listed, XLA compiles with
    them (an option XLA did not know would abort the process) and arrays are float64."""
    out = _child(RUN)
    listed = importlib.metadata.version("jaxlib").startswith(dejax.CPU_XLA_FLAGS_JAXLIB)
    assert all((flag in out) == listed for flag in dejax.CPU_XLA_FLAGS)
    assert out.endswith("float64 3.0")


def test_a_users_setting_of_an_option_is_kept():
    out = _child(RUN, env_xla="--xla_cpu_experimental_ynn_fusion_type=")
    assert out.split()[0] == "--xla_cpu_experimental_ynn_fusion_type="
    if importlib.metadata.version("jaxlib").startswith(dejax.CPU_XLA_FLAGS_JAXLIB):
        assert "LIBRARY_FUSION_TYPE_DOT" not in out and "--xla_cpu_use_fusion_emitters=false" in out


def test_unlisted_jaxlib_release_is_left_alone(monkeypatch):
    monkeypatch.setattr(importlib.metadata, "version", lambda name: "9.9.9")
    monkeypatch.setenv("XLA_FLAGS", "--some_flag=1")
    dejax._set_xla_flags()
    assert os.environ["XLA_FLAGS"] == "--some_flag=1"


@pytest.mark.parametrize("current", ["", "--other=2"])
def test_listed_release_appends_the_option(monkeypatch, current):
    monkeypatch.setattr(importlib.metadata, "version", lambda name: dejax.CPU_XLA_FLAGS_JAXLIB[0] + "7")
    monkeypatch.setenv("XLA_FLAGS", current)
    dejax._set_xla_flags()
    assert os.environ["XLA_FLAGS"] == " ".join([current, *dejax.CPU_XLA_FLAGS]).strip()
