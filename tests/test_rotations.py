"""Rotation conversions in float64: round trips, composition, degenerate input.

Bounds are float64 rounding counts (``tests.tolerances.float64_bound``: gamma_n with u = 2^-53,
any summation order, sin / cos / arctan2 counted as 4 ulp for numpy's AVX-512 SVML kernels) at
the values' magnitude, written out beside each check, times ``MARGIN``. The counts are first
order; 10x covers the second-order terms and any slack in the counting. A real error (a sign, a
transposed matrix, a float32 step) is off by 1e-7 or more, a million times these bounds.
"""

import numpy as np
import pytest

from dataset_tools import rotations as R
from tests.tolerances import float64_bound

MARGIN = 10
UNIT = 4
"""Roundings by which a quaternion from ``qnormalize`` misses unit norm: the sum of 4 squares
(gamma_4), halved by sqrt plus its rounding, and the division: 4 (observed 2)."""


@pytest.fixture
def quats():
    rng = np.random.default_rng(0)
    return R.qnormalize(rng.normal(size=(500, 4)))


def _same_rotation(q1, q2):
    """| |q1 . q2| - 1 |: of second order in the angle between q1 and q2, so of first order only
    in their norms' misses of 1 (and the dot product's own 4 roundings)."""
    return np.abs(np.abs(np.sum(q1 * q2, axis=-1)) - 1.0).max()


# Two unit quaternions, each normalised last (UNIT each), and their 4-term dot (4): 12 roundings.
SAME_ROTATION = MARGIN * float64_bound(2 * UNIT + 4)


def test_matrix_round_trip_float64(quats):
    assert _same_rotation(R.matrix_to_quat(R.quat_to_matrix(quats)), quats) < SAME_ROTATION
    matrices = R.quat_to_matrix(quats)
    # M(q) = (1 - |q|^2) I + |q|^2 M(q / |q|) for a quaternion off unit norm by 2 UNIT in |q|^2,
    # which moves M M^T by at most 4 * 2 UNIT = 32; each entry of M carries <= 5 roundings (two
    # squares, a sum, 1 - 2(...)), entering the 3-term row products twice at row sums <= sqrt 3
    # (2 * 5 * 3 * sqrt 3 = 52), and the products' own 3: 87 roundings (observed 15).
    orthogonality = MARGIN * float64_bound(8 * UNIT + 52 + 3)
    gram = np.einsum("nij,nkj->nik", matrices, matrices)
    np.testing.assert_allclose(
        gram, np.broadcast_to(np.eye(3), gram.shape), rtol=0, atol=orthogonality
    )
    # det: the scale off unit norm moves it by <= 4 * 2 UNIT = 32, the entries' 5 roundings by
    # their cofactors (9 * 5 = 45), LAPACK's 3x3 LU and the diagonal product ~ 9 * 3 * 2 + 2 = 56:
    # 133 roundings (observed 14).
    determinant = MARGIN * float64_bound(8 * UNIT + 45 + 56)
    np.testing.assert_allclose(np.linalg.det(matrices), 1.0, rtol=0, atol=determinant)


def test_6d_round_trip(quats):
    matrices = R.quat_to_matrix(quats)
    # Gram-Schmidt of M's first two columns against M: the columns miss unit norm and each other
    # by the orthogonality count above (87), which moves x by <= 87 / 2 + 5 (norm, division), the
    # projection by 87 + 48 and y by another 87 / 2 + 5; z = x cross y (2 per entry, <= 2 each
    # from x and y) against M's own third column (87): ~ 2 * 87 + 87 + 48 + 10 + 6 = 325
    # roundings (observed 8).
    gram_schmidt = MARGIN * float64_bound(325)
    np.testing.assert_allclose(
        R.sixd_to_matrix(R.matrix_to_6d(matrices)), matrices, rtol=0, atol=gram_schmidt
    )
    assert _same_rotation(R.sixd_to_quat(R.quat_to_6d(quats)), quats) < SAME_ROTATION
    # The 6-D vector is column 0 then column 1: the same products, copied.
    np.testing.assert_array_equal(R.quat_to_6d(quats)[:, :3], matrices[:, :, 0])


def test_axis_angle_round_trip_and_small_angles(quats):
    # axis_angle_to_quat does not normalise: its norm misses 1 by the cosine (4 ulp), and the
    # vector part's sine (4), division by the angle (1), product (1) and the angle's own norm
    # (3); cos^2 + sin^2 = 1 whatever the angle's error (which moves the axis, second order):
    # 13, then the input's UNIT and the dot's 4: 21 roundings (observed 4).
    bound = MARGIN * float64_bound(13 + UNIT + 4)
    assert _same_rotation(R.axis_angle_to_quat(R.quat_to_axis_angle(quats)), quats) < bound
    tiny = np.array([[1e-12, 0.0, 0.0], [0.0, 0.0, 0.0]])
    assert np.all(np.isfinite(R.axis_angle_to_quat(tiny)))
    # A quarter turn about y: w = cos(pi / 4) (4 ulp, and fl(pi / 2)'s 1 through the slope),
    # y = fl(pi / 2) sin(pi / 4) / |fl(pi / 2)| (4 + 1 + 3 + 1); entries 2 w y and 1 - 2 y^2
    # (2 each) at magnitude 1: <= 2 * 10 + 2 = 22 roundings (observed 2); the product with
    # (0, 0, 1) picks a column exactly.
    np.testing.assert_allclose(
        R.axis_angle_to_matrix(np.array([0.0, np.pi / 2, 0.0])) @ [0, 0, 1.0],
        [1, 0, 0],
        rtol=0,
        atol=MARGIN * float64_bound(22),
    )


def test_qrot_matches_matrix_and_qmul_composes(quats):
    rng = np.random.default_rng(1)
    v = rng.normal(size=(500, 3))
    size = np.linalg.norm(v, axis=-1).max()  # 4.1
    # Off unit norm, both sides are v + |q|^2 (R v - v): the same, so only roundings count.
    # qrot: two cross products (2 each, the second carrying the first's), w uv, two sums, the
    # final sum at up to 3 |v|: ~15; the matrix: entries <= 5 through 3-term products at row
    # sums <= sqrt 3 (9), the products' 3 (at sqrt 3 |v|, 6): 30 roundings at |v| (observed 3).
    np.testing.assert_allclose(
        R.qrot(quats, v),
        np.einsum("nij,nj->ni", R.quat_to_matrix(quats), v),
        rtol=0,
        atol=MARGIN * float64_bound(30, size),
    )
    other = quats[::-1]
    # qmul: 4-term products (4 per entry), so |q o|^2 misses 1 by 2 (UNIT + UNIT + 8) = 32,
    # moving qrot by 2 |v| per unit (64), and turning it by 2 * 8 (16); each side's other
    # quaternions off unit norm, 2 * 2 UNIT |v| each (16 * 3), and three qrots' 15 (45):
    # 173 roundings at |v| (observed 6).
    np.testing.assert_allclose(
        R.qrot(R.qmul(quats, other), v),
        R.qrot(quats, R.qrot(other, v)),
        rtol=0,
        atol=MARGIN * float64_bound(64 + 16 + 48 + 45, size),
    )
    # Two qrots (15 each), each off unit norm by 2 UNIT in |q|^2, 2 |v| per unit (16 each):
    # 62 roundings at |v| (observed 6).
    np.testing.assert_allclose(
        R.qrot(R.qinv(quats), R.qrot(quats, v)),
        v,
        rtol=0,
        atol=MARGIN * float64_bound(2 * 15 + 2 * 16, size),
    )


def test_qbetween_including_antiparallel():
    rng = np.random.default_rng(2)
    u, v = rng.normal(size=(2, 200, 3))
    rotated = R.qrot(R.qbetween(u, v), u)
    # q = (|u||v| + u.v, u x v) carries ~15 roundings of |u||v| (two norms, their product, a
    # 3-term dot, the sum; the cross product's 2) against its norm |u||v| 2 cos(phi / 2): its
    # direction is off by 15 K (K = 1 / (2 cos(phi / 2)), largest for the most nearly opposite
    # pair), plus 4 from normalising; the rotation doubles that; qrot's 15 and three
    # normalisations' 3 each: 30 K + 32 roundings at unit size (K = 11.8: observed 16.5).
    cos_angle = np.sum(u * v, -1) / (np.linalg.norm(u, axis=-1) * np.linalg.norm(v, axis=-1))
    opposition = (1 / np.sqrt(2 * (1 + cos_angle))).max()
    np.testing.assert_allclose(
        rotated / np.linalg.norm(rotated, axis=-1, keepdims=True),
        v / np.linalg.norm(v, axis=-1, keepdims=True),
        rtol=0,
        atol=MARGIN * float64_bound(30 * opposition + 32),
    )
    for direction in ([0, 1.0, 0], [1.0, 0, 0], [0.3, -0.2, 0.9]):
        d = np.array(direction)
        q = R.qbetween(d, -d)
        assert np.all(np.isfinite(q))
        # A half turn about a (w = 0): d + 2 a x (a x d) = -d + 2 (1 - |a|^2) d + 2 (a.d) a,
        # |a|^2 off 1 by two normalisations (16), a.d by the cross product over |d x helper|
        # >= 0.9 |d| (3 * 2), and qrot's 15: 37 roundings at |d| <= 1 (observed 1).
        np.testing.assert_allclose(R.qrot(q, d), -d, rtol=0, atol=MARGIN * float64_bound(37))
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
