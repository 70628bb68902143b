"""argparse value types (dejax.argtypes): conversions and the messages that name the option."""
import argparse

import pytest

from dejax import argtypes as A


@pytest.mark.parametrize("conv, text, message", [
    (A.positive("--dt"), "0", "--dt must be > 0, got 0"),
    (A.positive("--dt"), "nan", "--dt must be > 0, got nan"),
    (A.positive("--dt"), "abc", "--dt must be a number, got 'abc'"),
    (A.nonneg("--damping"), "-1", "--damping must be >= 0, got -1"),
    (A.int_at_least("--steps", 2), "1", "--steps must be >= 2, got 1"),
    (A.int_at_least("--steps", 2), "2.5", "--steps must be a whole number, got '2.5'"),
    (A.positive_int("--cycles"), "0", "--cycles must be >= 1, got 0"),
    (A.float_list("--freq"), "10,x", "--freq must be comma-separated numbers, got '10,x'"),
    (A.float_list("--freq"), ",", "--freq needs at least one number, got ','"),
    (A.mesh_shape, "2x2", "mesh must look like 12x20x4 (three positive integers), got '2x2'"),
    (A.mesh_shape, "2x0x1", "mesh must look like 12x20x4"),
    (A.rho_inf, "1.5", "--rho-inf must lie in [0, 1], got 1.5"),
])
def test_bad_values_name_the_option(conv, text, message):
    with pytest.raises(argparse.ArgumentTypeError) as e:
        conv(text)
    assert str(e.value).startswith(message)


def test_good_values():
    assert A.positive("--dt")("1e-3") == 1e-3
    assert A.nonneg("--damping")("0") == 0.0
    assert A.int_at_least("--n", 0)("0") == 0
    assert A.float_list("--freq")("10, 30,50") == [10.0, 30.0, 50.0]
    assert A.mesh_shape("12X20x4") == (12, 20, 4)
    assert A.rho_inf("0.8") == 0.8
