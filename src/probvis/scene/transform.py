"""4x4 affine transforms composed as Mitsuba composes them (each new operation multiplies from the left)."""
import numpy as np


def translate(v):
    m = np.eye(4)
    m[:3, 3] = v
    return m


def scale(v):
    return np.diag([v[0], v[1], v[2], 1.0])


def rotate(axis, angle_deg):
    """Right-handed rotation about `axis` by `angle_deg` degrees (Rodrigues' formula).

    Like Mitsuba 3, the axis is used as given, not normalised: a non-unit axis gives the same (non-rigid)
    matrix Mitsuba builds, so scenes render identically in both.
    """
    a = np.asarray(axis, dtype=np.float64)
    if not np.any(a):
        raise ValueError("rotation axis is zero")
    t = np.radians(angle_deg)
    c, s = np.cos(t), np.sin(t)
    k = np.array([[0.0, -a[2], a[1]], [a[2], 0.0, -a[0]], [-a[1], a[0], 0.0]])
    m = np.eye(4)
    m[:3, :3] = c * np.eye(3) + s * k + (1.0 - c) * np.outer(a, a)
    return m


def coordinate_system(z):
    """Mitsuba's orthonormal basis (x, y) of a unit vector z: Duff et al. (JCGT 2017), which fixes, for instance,
    where a cylinder's uv starts and which way a lookat without `up` is turned."""
    sign = 1.0 if z[2] >= 0.0 else -1.0
    a = -1.0 / (sign + z[2])
    b = z[0] * z[1] * a
    return (np.array([1.0 + sign * z[0] * z[0] * a, sign * b, -sign * z[0]]),
            np.array([b, sign + z[1] * z[1] * a, -z[1]]))


def look_at(origin, target, up=None):
    """Camera-to-world matrix: local +z looks at `target`, +y is `up`, +x is left (Mitsuba's convention). Without
    `up`, or with a zero one, Mitsuba's parser takes the first vector of `coordinate_system` of the view direction."""
    o = np.asarray(origin, dtype=np.float64)
    d = np.asarray(target, dtype=np.float64) - o
    if np.linalg.norm(d) == 0.0:
        raise ValueError("lookat origin and target coincide")
    d /= np.linalg.norm(d)
    if up is None or not np.abs(np.asarray(up, dtype=np.float64)).max() > 0.0:  # no up, or a zero one: Mitsuba's
        up = coordinate_system(d)[0]
    up = tamed(up)  # the direction is what counts: 1e300 must not overflow
    left = np.cross(up, d)
    if np.linalg.norm(left) < 1e-12 * np.linalg.norm(up):  # the sine of their angle: a short `up` is as good
        raise ValueError("lookat 'up' is parallel to the viewing direction")
    left /= np.linalg.norm(left)
    new_up = np.cross(d, left)
    m = np.eye(4)
    m[:3, 0], m[:3, 1], m[:3, 2], m[:3, 3] = left, new_up, d, o
    return m


def _times_columns(p, a):
    """p @ a for points p (..., 3) and a 3x3 matrix a, column by column: a matrix product this narrow gains
    nothing from BLAS, whose first call in a process also starts its thread pool (a quarter of a second)."""
    p = np.asarray(p, dtype=np.float64)
    return p[..., 0:1] * a[0] + p[..., 1:2] * a[1] + p[..., 2:3] * a[2]


def apply_points(m, p):
    return _times_columns(p, m[:3, :3].T) + m[:3, 3]


def tamed(v):
    """Directions (..., 3) whose largest component lies beyond [1e-30, 1e30] rescaled to a largest component of 1,
    so that their products and norms neither overflow nor underflow (a file's normal of 1e200); the others as
    given, bit for bit."""
    v = np.asarray(v, dtype=np.float64)
    size = np.abs(v).max(axis=-1, keepdims=True)
    wild = (size > 1e30) | ((size < 1e-30) & (size > 0.0))
    return np.where(wild, v / np.where(wild, size, 1.0), v) if np.any(wild) else v


def apply_normals(m, n):
    """Normals transform with the inverse transpose; the result is normalised."""
    out = _times_columns(tamed(n), np.linalg.inv(m[:3, :3]))
    return out / np.maximum(np.linalg.norm(out, axis=-1, keepdims=True), 1e-300)
