"""Helpers shared by several test modules (imported as ``helpers``, like ``svk``)."""
import jax.numpy as jnp
import pytest

from dejax import integrate as it
from dejax import model as mdl
from fitting.schema import DataError


# a hand-made trace file: a comment line, units in the header, a comment between data rows
CSV = """\
# hand-made trace: time in ms, displacement in mm, voltage in kV
t_ms,disp_mm,U_kV,note
0,0.0,0.0,start
1,0.5,1.5,
2,1.0,3.0,x
# a comment between data rows
3,1.5,4.5,
"""


def raises(match_parts, fn, *args, **kw):
    """Call fn, expect DataError whose message contains every part."""
    with pytest.raises(DataError) as info:
        fn(*args, **kw)
    msg = str(info.value)
    for part in match_parts:
        assert part in msg, f"{part!r} not in message: {msg}"
    return info.value


def rest_state(m):
    """The reference state at rest (what integrate.initial_state gives without load)."""
    z = jnp.zeros_like(m.q0)
    return it.State(t=jnp.asarray(0.0), q=m.q0, v=z, qdd=z, a=z, Cv=mdl.initial_viscous_state(m))
