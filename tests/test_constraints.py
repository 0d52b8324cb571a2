import numpy as np
import pytest

from vtm_pin import TransitionError
from vtm_pin.numerics.constraints import lock_jacobian, orthogonal_complement


def test_lock_jacobian_has_unit_rows():
    J = lock_jacobian(4, [2, 0])
    np.testing.assert_array_equal(J, [[0, 0, 1, 0], [1, 0, 0, 0]])
    assert lock_jacobian(3, []).shape == (0, 3)


def test_complement_of_locks_selects_free_joints():
    F, s = orthogonal_complement(lock_jacobian(3, [1]))
    np.testing.assert_array_equal(s, [0, 2])
    np.testing.assert_array_equal(F, [[1, 0], [0, 0], [0, 1]])  # the paper's F1 for example 1


def test_complement_of_general_jacobian():
    rng = np.random.default_rng(4)
    J = rng.normal(size=(3, 7))
    F, s = orthogonal_complement(J)
    assert F.shape == (7, 4)
    np.testing.assert_allclose(J @ F, 0.0, atol=1e-12)
    np.testing.assert_array_equal(F[s], np.eye(4))


def test_redundant_constraints_raise():
    J = np.array([[1.0, 0.0, 0.0], [2.0, 0.0, 0.0]])
    with pytest.raises(TransitionError, match="constraints are redundant"):
        orthogonal_complement(J)
