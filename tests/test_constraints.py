"""Linear constraints by elimination (dejax.constraints): coordinate indices, face pins,
and the split of fixed, prescribed and tied coordinates into reduced unknowns."""
import numpy as np
import pytest

from dejax import constraints as cs


def test_dof_index_is_12_node_plus_3_slot_plus_component():
    np.testing.assert_array_equal(cs.dof_index([0, 2], 1, 2), [5, 29])
    assert cs.dof_index(3, cs.POSITION, 0) == 36


def test_face_dofs_pin_the_position_and_the_two_in_face_gradients():
    # face normal to x: component 1 of r, dr/dY (slot 2) and dr/dZ (slot 3), not dr/dX
    got = cs.face_dofs([0, 1], 0, [1])
    want = np.sort([12 * n + 3 * s + 1 for n in (0, 1) for s in (0, 2, 3)])
    np.testing.assert_array_equal(got, want)
    assert cs.face_dofs([0], 2, []).size == 0
    with pytest.raises(ValueError, match="normal_axis"):
        cs.face_dofs([0], 3, [0])
    with pytest.raises(ValueError, match="component"):
        cs.face_dofs([0], 0, [3])


def test_split_fixed_prescribed_and_tied():
    c = cs.Constraints(24).fix([0, 1]).prescribe([12, 13], [1.0, 0.5]).tie([3, 15, 1])
    assert c.n_channels == 1
    col, constrained, dirs, reps = c.split()
    np.testing.assert_array_equal(constrained, [0, 1, 12, 13])
    assert np.all(col[constrained] == -1)
    # the tie keeps its constrained member (1) constrained and joins 3 and 15 in unknown 0
    assert col[3] == col[15] == 0 and reps[0] == 3
    free = [i for i in range(24) if i not in (0, 1, 12, 13, 3, 15)]
    np.testing.assert_array_equal(col[free], np.arange(1, 1 + len(free)))
    np.testing.assert_array_equal(reps[1:], free)
    np.testing.assert_allclose(dirs, [[0.0, 0.0, 1.0, 0.5]])
    # T: every row at most one 1; q = q_p + T z reproduces the tie
    T = np.zeros((24, col.max() + 1))
    T[np.nonzero(col >= 0)[0], col[col >= 0]] = 1.0
    assert np.all(T.sum(axis=1) <= 1)


def test_constraints_are_immutable_and_checked():
    c0 = cs.Constraints(12)
    c1 = c0.fix([2])
    assert c0.fixed.size == 0 and list(c1.fixed) == [2]
    assert c1.tie([5]) is c1  # a single coordinate ties to nothing
    with pytest.raises(ValueError, match="outside 0..11"):
        c0.fix([12])
    with pytest.raises(ValueError, match="outside 0..11"):
        c0.prescribe([-1], 1.0)
