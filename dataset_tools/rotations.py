"""Batched rotation conversions in numpy.

Conventions: quaternions are ``(..., 4)`` with the scalar first (w, x, y, z) and act on column
vectors; rotation matrices are ``(..., 3, 3)``; the 6-D representation is the first two columns of
the matrix, concatenated (column 0 then column 1); axis-angle is ``(..., 3)`` (axis times angle in
radians). Every function returns a new array and accepts any leading batch shape.
"""

from __future__ import annotations

import numpy as np

_EPS = 1e-12


def _check_last(x: np.ndarray, size: int, name: str) -> np.ndarray:
    x = np.asarray(x)
    if x.shape[-1:] != (size,):
        raise ValueError(f"{name} must have shape (..., {size}), got {x.shape}")
    return x


def cross(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Cross product of vectors (..., 3) (broadcasting); cheaper than np.cross on small arrays."""
    a0, a1, a2 = a[..., 0], a[..., 1], a[..., 2]
    b0, b1, b2 = b[..., 0], b[..., 1], b[..., 2]
    return np.stack([a1 * b2 - a2 * b1, a2 * b0 - a0 * b2, a0 * b1 - a1 * b0], axis=-1)


def qnormalize(q: np.ndarray) -> np.ndarray:
    """Unit quaternions (..., 4); a zero quaternion raises ValueError."""
    q = _check_last(q, 4, "quaternion")
    norm = np.linalg.norm(q, axis=-1, keepdims=True)
    if np.any(norm < _EPS):
        raise ValueError("cannot normalise a zero quaternion")
    return q / norm


def qmul(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Hamilton product a * b of quaternions (..., 4) (broadcasting)."""
    a = _check_last(a, 4, "quaternion")
    b = _check_last(b, 4, "quaternion")
    aw, ax, ay, az = a[..., 0], a[..., 1], a[..., 2], a[..., 3]
    bw, bx, by, bz = b[..., 0], b[..., 1], b[..., 2], b[..., 3]
    return np.stack(
        [
            aw * bw - ax * bx - ay * by - az * bz,
            aw * bx + ax * bw + ay * bz - az * by,
            aw * by - ax * bz + ay * bw + az * bx,
            aw * bz + ax * by - ay * bx + az * bw,
        ],
        axis=-1,
    )


def qinv(q: np.ndarray) -> np.ndarray:
    """Inverse of unit quaternions (the conjugate)."""
    q = _check_last(q, 4, "quaternion")
    return q * np.array([1.0, -1.0, -1.0, -1.0], dtype=q.dtype if q.dtype.kind == "f" else None)


def qrot(q: np.ndarray, v: np.ndarray) -> np.ndarray:
    """Rotate vectors v (..., 3) by unit quaternions q (..., 4) (broadcasting)."""
    q = _check_last(q, 4, "quaternion")
    v = _check_last(v, 3, "vector")
    w = q[..., :1]
    u = q[..., 1:]
    uv = cross(u, v)
    return v + 2.0 * (w * uv + cross(u, uv))


def qbetween(u: np.ndarray, v: np.ndarray) -> np.ndarray:
    """Shortest-arc unit quaternions (..., 4) rotating directions u onto v (..., 3).

    Anti-parallel pairs get a half turn about an axis perpendicular to u; a zero-length input
    raises ValueError.
    """
    u = _check_last(u, 3, "vector").astype(np.float64, copy=False)
    v = _check_last(v, 3, "vector").astype(np.float64, copy=False)
    u, v = np.broadcast_arrays(u, v)
    nu = np.linalg.norm(u, axis=-1, keepdims=True)
    nv = np.linalg.norm(v, axis=-1, keepdims=True)
    if np.any(nu < _EPS) or np.any(nv < _EPS):
        raise ValueError("qbetween got a zero-length vector")
    w = nu * nv + np.sum(u * v, axis=-1, keepdims=True)
    q = np.concatenate([w, cross(u, v)], axis=-1)
    norm = np.linalg.norm(q, axis=-1, keepdims=True)
    degenerate = (norm < 1e-9 * nu * nv)[..., 0]
    if np.any(degenerate):
        # Anti-parallel: rotate half a turn about any axis perpendicular to u.
        ud = u[degenerate]
        helper = np.where(np.abs(ud[:, :1]) < 0.9, [[1.0, 0.0, 0.0]], [[0.0, 1.0, 0.0]])
        axis = cross(ud, helper)
        axis /= np.linalg.norm(axis, axis=-1, keepdims=True)
        q = q.copy()
        q[degenerate] = np.concatenate([np.zeros((len(axis), 1)), axis], axis=-1)
        norm = np.linalg.norm(q, axis=-1, keepdims=True)
    return q / norm


def quat_to_matrix(q: np.ndarray) -> np.ndarray:
    """Rotation matrices (..., 3, 3) of unit quaternions (..., 4)."""
    q = _check_last(q, 4, "quaternion")
    w, x, y, z = q[..., 0], q[..., 1], q[..., 2], q[..., 3]
    xx, yy, zz = x * x, y * y, z * z
    xy, xz, yz, wx, wy, wz = x * y, x * z, y * z, w * x, w * y, w * z
    rows = [
        1 - 2 * (yy + zz), 2 * (xy - wz), 2 * (xz + wy),
        2 * (xy + wz), 1 - 2 * (xx + zz), 2 * (yz - wx),
        2 * (xz - wy), 2 * (yz + wx), 1 - 2 * (xx + yy),
    ]  # fmt: skip
    return np.stack(rows, axis=-1).reshape(q.shape[:-1] + (3, 3))


def matrix_to_quat(m: np.ndarray) -> np.ndarray:
    """Unit quaternions (..., 4) with w >= 0 of rotation matrices (..., 3, 3)."""
    m = np.asarray(m, dtype=np.float64)
    if m.shape[-2:] != (3, 3):
        raise ValueError(f"matrix must have shape (..., 3, 3), got {m.shape}")
    m00, m11, m22 = m[..., 0, 0], m[..., 1, 1], m[..., 2, 2]
    # Four candidate solutions; take, per matrix, the best conditioned one.
    candidates = np.stack(
        [
            np.stack([1 + m00 + m11 + m22, m[..., 2, 1] - m[..., 1, 2],
                      m[..., 0, 2] - m[..., 2, 0], m[..., 1, 0] - m[..., 0, 1]], -1),
            np.stack([m[..., 2, 1] - m[..., 1, 2], 1 + m00 - m11 - m22,
                      m[..., 0, 1] + m[..., 1, 0], m[..., 0, 2] + m[..., 2, 0]], -1),
            np.stack([m[..., 0, 2] - m[..., 2, 0], m[..., 0, 1] + m[..., 1, 0],
                      1 - m00 + m11 - m22, m[..., 1, 2] + m[..., 2, 1]], -1),
            np.stack([m[..., 1, 0] - m[..., 0, 1], m[..., 0, 2] + m[..., 2, 0],
                      m[..., 1, 2] + m[..., 2, 1], 1 - m00 - m11 + m22], -1),
        ],
        axis=-2,
    )  # fmt: skip
    diag = np.stack(
        [1 + m00 + m11 + m22, 1 + m00 - m11 - m22, 1 - m00 + m11 - m22, 1 - m00 - m11 + m22], -1
    )
    best = np.argmax(diag, axis=-1)
    q = np.take_along_axis(candidates, best[..., None, None], axis=-2)[..., 0, :]
    q = q / np.linalg.norm(q, axis=-1, keepdims=True)
    return np.where(q[..., :1] < 0, -q, q)


def matrix_to_6d(m: np.ndarray) -> np.ndarray:
    """6-D representation (..., 6): the first two columns of m (..., 3, 3), column 0 first."""
    m = np.asarray(m)
    if m.shape[-2:] != (3, 3):
        raise ValueError(f"matrix must have shape (..., 3, 3), got {m.shape}")
    return np.concatenate([m[..., :, 0], m[..., :, 1]], axis=-1)


def sixd_to_matrix(d6: np.ndarray) -> np.ndarray:
    """Rotation matrices (..., 3, 3) from 6-D (..., 6) by Gram-Schmidt; degenerate input raises."""
    d6 = _check_last(d6, 6, "6-D rotation").astype(np.float64, copy=False)
    a, b = d6[..., :3], d6[..., 3:]
    na = np.linalg.norm(a, axis=-1, keepdims=True)
    if np.any(na < _EPS):
        raise ValueError("6-D rotation has a zero first column")
    x = a / na
    b = b - np.sum(x * b, axis=-1, keepdims=True) * x
    nb = np.linalg.norm(b, axis=-1, keepdims=True)
    if np.any(nb < _EPS):
        raise ValueError("6-D rotation has parallel columns")
    y = b / nb
    z = cross(x, y)
    return np.stack([x, y, z], axis=-1)


def quat_to_6d(q: np.ndarray) -> np.ndarray:
    """6-D representation (..., 6) of unit quaternions (..., 4)."""
    return matrix_to_6d(quat_to_matrix(q))


def sixd_to_quat(d6: np.ndarray) -> np.ndarray:
    """Unit quaternions (..., 4) of 6-D rotations (..., 6)."""
    return matrix_to_quat(sixd_to_matrix(d6))


def axis_angle_to_quat(aa: np.ndarray) -> np.ndarray:
    """Unit quaternions (..., 4) of axis-angle vectors (..., 3); stable near zero angle."""
    aa = _check_last(aa, 3, "axis-angle").astype(np.float64, copy=False)
    angle = np.linalg.norm(aa, axis=-1, keepdims=True)
    half = 0.5 * angle
    small = angle < 1e-8
    # sin(a/2)/a, with its Taylor expansion near zero.
    scale = np.where(small, 0.5 - angle**2 / 48.0, np.sin(half) / np.where(small, 1.0, angle))
    return np.concatenate([np.cos(half), aa * scale], axis=-1)


def axis_angle_to_matrix(aa: np.ndarray) -> np.ndarray:
    """Rotation matrices (..., 3, 3) of axis-angle vectors (..., 3)."""
    return quat_to_matrix(axis_angle_to_quat(aa))


def quat_to_axis_angle(q: np.ndarray) -> np.ndarray:
    """Axis-angle vectors (..., 3), angle in [0, pi], of unit quaternions (..., 4)."""
    q = qnormalize(q)
    q = np.where(q[..., :1] < 0, -q, q)
    sin_half = np.linalg.norm(q[..., 1:], axis=-1, keepdims=True)
    angle = 2.0 * np.arctan2(sin_half, q[..., :1])
    small = sin_half < 1e-8
    scale = np.where(small, 2.0, angle / np.where(small, 1.0, sin_half))
    return q[..., 1:] * scale


def yaw_quat(angle: np.ndarray | float) -> np.ndarray:
    """Quaternions (..., 4) of rotations by ``angle`` radians about +Y."""
    angle = np.asarray(angle, dtype=np.float64)
    zeros = np.zeros_like(angle)
    return np.stack([np.cos(angle / 2), zeros, np.sin(angle / 2), zeros], axis=-1)


# ----------------------------------------------------------------------------- world frames
# The dataset's world is y-up; z-up files (AMASS, the demo corpus) and matplotlib's 3D axes are
# met by the one proper rotation between them (-90 / +90 degrees about x), never by a reflection,
# so left and right survive the conversion.


def y_up_to_z_up(points: np.ndarray) -> np.ndarray:
    """(..., 3) y-up points to z-up: (x, y, z) -> (x, -z, y)."""
    points = np.asarray(points)
    return np.stack([points[..., 0], -points[..., 2], points[..., 1]], axis=-1)


def z_up_to_y_up(points: np.ndarray) -> np.ndarray:
    """(..., 3) z-up points to y-up: (x, y, z) -> (x, z, -y); the inverse of :func:`y_up_to_z_up`."""
    points = np.asarray(points)
    return np.stack([points[..., 0], points[..., 2], -points[..., 1]], axis=-1)


def to_y_up(points: np.ndarray, up: str) -> np.ndarray:
    """(..., 3) points whose up axis is ``up`` ("y" or "z") in the y-up frame."""
    if up == "y":
        return np.asarray(points)
    if up == "z":
        return z_up_to_y_up(points)
    raise ValueError(f"up axis must be 'y' or 'z', got {up!r}")
