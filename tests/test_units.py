"""Units of trace channels (fitting.units): conversion to SI and the errors for unknown units."""
import numpy as np
import pytest

from fitting.schema import DataError
from fitting.units import CHANNELS, SI_UNIT, UNITS, to_si


def test_every_channel_has_an_si_unit_and_converts_from_it_unchanged():
    for channel, quantity in CHANNELS.items():
        si = SI_UNIT[quantity]
        assert UNITS[quantity][si] == (1.0, 0.0), channel
        np.testing.assert_array_equal(to_si([1.5, -2.0], si, channel), [1.5, -2.0])


@pytest.mark.parametrize("values, unit, channel, expected", [
    ([1.0, 2.5], "ms", "time", [1e-3, 2.5e-3]),
    ([3.0], "mm", "displacement", [3e-3]),
    ([1.5], "kV", "voltage", [1500.0]),
    ([2.0], "kV/mm", "field", [2e6]),
    ([12.5], "kPa", "stress", [12.5e3]),
    ([180.0], "deg", "angle", [np.pi]),
    ([20.0], "degC", "temperature", [293.15]),
    ([50.0], "%", "strain", [0.5]),
])
def test_to_si(values, unit, channel, expected):
    np.testing.assert_allclose(to_si(values, unit, channel), expected, rtol=1e-15)


def test_unknown_unit_names_the_channel_lists_the_known_and_suggests():
    with pytest.raises(DataError) as e:
        to_si([1.0], "kv", "voltage", file="exp.toml")
    msg = str(e.value)
    assert msg.startswith("exp.toml: units.voltage: unknown unit 'kv' for channel 'voltage' (voltage)")
    assert "did you mean 'kV'" in msg and "known units: V, mV, kV, MV" in msg
    assert e.value.key == "units.voltage"
