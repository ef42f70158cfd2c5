import numpy as np
import pytest

from dataset_tools import rotations as R


@pytest.fixture
def quats():
    rng = np.random.default_rng(0)
    return R.qnormalize(rng.normal(size=(500, 4)))


def _same_rotation(q1, q2):
    return np.abs(np.abs(np.sum(q1 * q2, axis=-1)) - 1.0).max()


def test_matrix_round_trip_float64(quats):
    assert _same_rotation(R.matrix_to_quat(R.quat_to_matrix(quats)), quats) < 1e-12
    matrices = R.quat_to_matrix(quats)
    assert np.allclose(np.einsum("nij,nkj->nik", matrices, matrices), np.eye(3), atol=1e-12)
    assert np.allclose(np.linalg.det(matrices), 1.0, atol=1e-12)


def test_6d_round_trip(quats):
    matrices = R.quat_to_matrix(quats)
    assert np.abs(R.sixd_to_matrix(R.matrix_to_6d(matrices)) - matrices).max() < 1e-12
    assert _same_rotation(R.sixd_to_quat(R.quat_to_6d(quats)), quats) < 1e-12
    # The 6-D vector is column 0 then column 1.
    assert np.allclose(R.quat_to_6d(quats)[:, :3], matrices[:, :, 0])


def test_axis_angle_round_trip_and_small_angles(quats):
    assert _same_rotation(R.axis_angle_to_quat(R.quat_to_axis_angle(quats)), quats) < 1e-12
    tiny = np.array([[1e-12, 0.0, 0.0], [0.0, 0.0, 0.0]])
    assert np.all(np.isfinite(R.axis_angle_to_quat(tiny)))
    assert np.allclose(
        R.axis_angle_to_matrix(np.array([0.0, np.pi / 2, 0.0])) @ [0, 0, 1.0], [1, 0, 0]
    )


def test_qrot_matches_matrix_and_qmul_composes(quats):
    rng = np.random.default_rng(1)
    v = rng.normal(size=(500, 3))
    assert np.allclose(R.qrot(quats, v), np.einsum("nij,nj->ni", R.quat_to_matrix(quats), v))
    other = quats[::-1]
    assert np.allclose(R.qrot(R.qmul(quats, other), v), R.qrot(quats, R.qrot(other, v)))
    assert np.allclose(R.qrot(R.qinv(quats), R.qrot(quats, v)), v)


def test_qbetween_including_antiparallel():
    rng = np.random.default_rng(2)
    u, v = rng.normal(size=(2, 200, 3))
    rotated = R.qrot(R.qbetween(u, v), u)
    assert np.allclose(
        rotated / np.linalg.norm(rotated, axis=-1, keepdims=True),
        v / np.linalg.norm(v, axis=-1, keepdims=True),
    )
    for direction in ([0, 1.0, 0], [1.0, 0, 0], [0.3, -0.2, 0.9]):
        d = np.array(direction)
        q = R.qbetween(d, -d)
        assert np.all(np.isfinite(q))
        assert np.allclose(R.qrot(q, d), -d)
    with pytest.raises(ValueError, match="zero-length"):
        R.qbetween(np.zeros(3), np.ones(3))


def test_bad_shapes_and_degenerate_raise():
    with pytest.raises(ValueError):
        R.qmul(np.ones(3), np.ones(4))
    with pytest.raises(ValueError):
        R.qnormalize(np.zeros(4))
    with pytest.raises(ValueError):
        R.sixd_to_matrix(np.array([1.0, 0, 0, 2.0, 0, 0]))
    with pytest.raises(ValueError):
        R.matrix_to_6d(np.eye(4))
