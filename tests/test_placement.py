"""fitting.placement: one-element fits and diagnoses move to the host CPU when the default
backend is an accelerator (a GPU is slower for them: measured on an H200), and only then."""
import argparse
from pathlib import Path

import jax
import jax.numpy as jnp
import pytest

from fitting import cli as fitting_cli
from fitting import placement
from fitting.data import load_experiment

EXAMPLES = Path(__file__).resolve().parents[1] / "data" / "examples"
CPU = jax.devices("cpu")[0]


def test_one_element_problems_move_to_the_cpu_on_an_accelerator_only():
    assert placement.device_for(1, "auto", backend="gpu") == CPU
    assert placement.device_for(32, "auto", backend="gpu") is None   # the tube 4x8x1: faster on the GPU
    assert placement.device_for(1, "auto", backend="cpu") is None
    assert placement.device_for(32, "cpu", backend="gpu") == CPU
    assert placement.device_for(1, "default", backend="gpu") is None
    with pytest.raises(ValueError, match="auto, cpu, default"):
        placement.device_for(1, "host")


def test_n_elements_of_the_example_experiments():
    assert placement.n_elements(load_experiment(EXAMPLES / "vhb4910_uniaxial.toml")) == 1
    assert placement.n_elements(load_experiment(EXAMPLES / "block_d1.toml")) == 1
    assert placement.n_elements(load_experiment(EXAMPLES / "tube_example.toml")) == 32


def test_placed_sets_the_default_device():
    with placement.placed(CPU):
        assert jnp.zeros(3).devices() == {CPU}
    with placement.placed(None):
        assert jnp.zeros(3).devices() == {jax.devices()[0]}


@pytest.mark.parametrize("verb", ["fit", "diagnose"])
def test_device_option_of_fit_and_diagnose(verb, capsys):
    ap = argparse.ArgumentParser(prog="dejax")
    sub = ap.add_subparsers(dest="command", required=True)
    fitting_cli.register_fit(sub)
    fitting_cli.register_diagnose(sub)
    assert ap.parse_args([verb, "x.toml"]).device == "auto"
    assert ap.parse_args([verb, "x.toml", "--device", "cpu"]).device == "cpu"
    with pytest.raises(SystemExit):
        ap.parse_args([verb, "x.toml", "--device", "tpu"])
    assert "invalid choice: 'tpu'" in capsys.readouterr().err


def test_fit_says_when_it_moves_a_run_to_the_cpu(monkeypatch, capsys):
    monkeypatch.setattr(jax, "default_backend", lambda: "gpu")
    exp = load_experiment(EXAMPLES / "vhb4910_uniaxial.toml")
    assert fitting_cli._device(argparse.Namespace(device="auto", quiet=False), exp, "fit") == CPU
    assert "1-element problem: running on the host CPU, faster than the GPU" in capsys.readouterr().out
    assert fitting_cli._device(argparse.Namespace(device="default", quiet=False), exp, "fit") is None
    tube = load_experiment(EXAMPLES / "tube_example.toml")
    assert fitting_cli._device(argparse.Namespace(device="auto", quiet=False), tube, "diagnose") is None
    assert capsys.readouterr().out == ""
