"""Rotations and rigid transforms with the conventions of DESIGN.md.

Conventions
-----------
* Euler angles are intrinsic Z-Y'-X'': ``R = Rz(yaw) @ Ry(pitch) @ Rx(roll)``.
* ``A_in_B`` is the pose of frame A expressed in frame B: it maps A coordinates to B coordinates,
  ``p_B = A_in_B.apply(p_A)``.
* Inside the package everything is SI (m, rad). The ``{x_mm, ..., yaw_deg}`` dictionaries of YAML
  and JSON are converted only by :func:`transform_from_dict` and :meth:`Transform.to_dict`.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass, field

import numpy as np
from numpy.typing import ArrayLike, NDArray

POSE_KEYS = ("x_mm", "y_mm", "z_mm", "roll_deg", "pitch_deg", "yaw_deg")
_PLANES = ((1, 2), (2, 0), (0, 1))  # the plane (i, j) each basis axis rotates


def matrix_from_axis_angle(axis: int, angle: float) -> NDArray[np.float64]:
    """Rotation matrix (3, 3) about a basis axis (0 = X, 1 = Y, 2 = Z) by ``angle`` rad."""
    if axis not in (0, 1, 2):
        raise ValueError(f"axis must be 0, 1 or 2, got {axis!r}")
    c, s = np.cos(angle), np.sin(angle)
    i, j = _PLANES[axis]
    # zeros and one set element instead of np.eye: 2 us a matrix instead of 7, and the pose search and the
    # pitch scan build 90,000 of them over the bench's 34 frames (0.3 s of 18 profiled)
    R = np.zeros((3, 3))
    R[axis, axis] = 1.0
    R[i, i] = c
    R[j, j] = c
    R[i, j] = -s
    R[j, i] = s
    return R


def matrix_from_euler(yaw: float, pitch: float, roll: float) -> NDArray[np.float64]:
    """Rotation matrix (3, 3) ``Rz(yaw) @ Ry(pitch) @ Rx(roll)``; angles in rad."""
    return matrix_from_axis_angle(2, yaw) @ matrix_from_axis_angle(1, pitch) @ matrix_from_axis_angle(0, roll)


def euler_from_matrix(R: ArrayLike) -> tuple[float, float, float]:
    """Inverse of :func:`matrix_from_euler`: ``(yaw, pitch, roll)`` in rad.

    At gimbal lock (``|pitch| = pi/2``) roll is set to zero and yaw takes the whole rotation.
    """
    return _euler_from_rotation(check_rotation(R))


def _euler_from_rotation(R: NDArray[np.float64]) -> tuple[float, float, float]:
    """:func:`euler_from_matrix` of a rotation already checked."""
    pitch = float(np.arcsin(np.clip(-R[2, 0], -1.0, 1.0)))
    if abs(R[2, 0]) < 1.0 - 1e-12:
        yaw = float(np.arctan2(R[1, 0], R[0, 0]))
        roll = float(np.arctan2(R[2, 1], R[2, 2]))
    else:
        yaw = float(np.arctan2(-R[0, 1], R[1, 1]))
        roll = 0.0
    return yaw, pitch, roll


def check_rotation(R: ArrayLike, tolerance: float = 1e-6) -> NDArray[np.float64]:
    """Return ``R`` as a float (3, 3) array after checking it is a proper rotation.

    Raises
    ------
    ValueError
        If the shape is not (3, 3), ``R`` is not orthonormal or its determinant is not +1.
    """
    R = np.asarray(R, dtype=float)
    if R.shape != (3, 3):
        raise ValueError(f"rotation matrix must have shape (3, 3), got {R.shape}")
    if not np.all(np.isfinite(R)):
        raise ValueError("rotation matrix holds NaN or infinity")
    if np.abs(R @ R.T - np.eye(3)).max() > tolerance:
        raise ValueError("rotation matrix is not orthonormal")
    if np.linalg.det(R) < 0:
        raise ValueError("rotation matrix is a reflection (determinant -1)")
    return R


@dataclass(frozen=True)
class Transform:
    """Rigid transform ``A_in_B``: ``p_B = rotation @ p_A + translation``.

    Attributes
    ----------
    rotation : ndarray, shape (3, 3)
    translation : ndarray, shape (3,), metres
    """

    rotation: NDArray[np.float64] = field(default_factory=lambda: np.eye(3))
    translation: NDArray[np.float64] = field(default_factory=lambda: np.zeros(3))

    def __post_init__(self) -> None:
        R = check_rotation(self.rotation)
        t = np.asarray(self.translation, dtype=float)
        if t.shape != (3,) or not np.all(np.isfinite(t)):
            raise ValueError(f"translation must be 3 finite numbers, got {t!r}")
        R.setflags(write=False)
        t = t.copy()
        t.setflags(write=False)
        object.__setattr__(self, "rotation", R)
        object.__setattr__(self, "translation", t)

    @classmethod
    def _built(cls, rotation: NDArray[np.float64], translation: NDArray[np.float64]) -> Transform:
        """A transform from a rotation that is proper by construction (Euler angles, products and
        transposes of checked ones): only finiteness is checked. The full check costs 20 us, and the
        pose search builds thousands of transforms a measurement."""
        R, t = np.array(rotation, dtype=float), np.array(translation, dtype=float)
        if not (np.isfinite(R).all() and np.isfinite(t).all()):
            raise ValueError(f"transform must be finite, got rotation {R.tolist()} and translation {t.tolist()}")
        R.setflags(write=False)
        t.setflags(write=False)
        built = object.__new__(cls)
        object.__setattr__(built, "rotation", R)
        object.__setattr__(built, "translation", t)
        return built

    @classmethod
    def from_euler(
        cls, x: float = 0.0, y: float = 0.0, z: float = 0.0, roll: float = 0.0, pitch: float = 0.0, yaw: float = 0.0
    ) -> Transform:
        """Transform from a translation (m) and Z-Y'-X'' Euler angles (rad)."""
        return cls._built(matrix_from_euler(yaw, pitch, roll), np.array([x, y, z], dtype=float))

    @classmethod
    def from_matrix(cls, T: ArrayLike) -> Transform:
        """Transform from a homogeneous (4, 4) matrix."""
        T = np.asarray(T, dtype=float)
        if T.shape != (4, 4):
            raise ValueError(f"homogeneous matrix must have shape (4, 4), got {T.shape}")
        if not np.allclose(T[3], [0, 0, 0, 1]):
            raise ValueError("last row of a homogeneous matrix must be [0, 0, 0, 1]")
        return cls(T[:3, :3], T[:3, 3])

    @property
    def matrix(self) -> NDArray[np.float64]:
        """Homogeneous matrix (4, 4)."""
        T = np.eye(4)
        T[:3, :3] = self.rotation
        T[:3, 3] = self.translation
        return T

    @property
    def euler(self) -> tuple[float, float, float]:
        """``(yaw, pitch, roll)`` in rad."""
        return _euler_from_rotation(self.rotation)

    @property
    def quaternion(self) -> NDArray[np.float64]:
        """The rotation's unit quaternion ``(x, y, z, w)``, ``w >= 0`` (:func:`quaternion_from_matrix`)."""
        return _quaternion_from_rotation(self.rotation)

    def inverse(self) -> Transform:
        """``B_in_A`` from ``A_in_B``."""
        Rt = self.rotation.T
        return Transform._built(Rt, -Rt @ self.translation)

    def __matmul__(self, other: Transform) -> Transform:
        """Compose: ``B_in_C @ A_in_B = A_in_C``."""
        if not isinstance(other, Transform):
            return NotImplemented
        return Transform._built(self.rotation @ other.rotation, self.rotation @ other.translation + self.translation)

    def apply(self, points: ArrayLike) -> NDArray[np.float64]:
        """Map points (N, 3) or (3,) from frame A to frame B."""
        p = np.asarray(points, dtype=float)
        if p.shape[-1] != 3:
            raise ValueError(f"points must have a last dimension of 3, got shape {p.shape}")
        return p @ self.rotation.T + self.translation

    def apply_direction(self, directions: ArrayLike) -> NDArray[np.float64]:
        """Rotate directions (N, 3) or (3,) from frame A to frame B (no translation)."""
        d = np.asarray(directions, dtype=float)
        if d.shape[-1] != 3:
            raise ValueError(f"directions must have a last dimension of 3, got shape {d.shape}")
        return d @ self.rotation.T

    def to_dict(self) -> dict[str, float]:
        """The ``{x_mm, y_mm, z_mm, roll_deg, pitch_deg, yaw_deg}`` form of DESIGN.md."""
        yaw, pitch, roll = self.euler
        x, y, z = (float(v) * 1000.0 for v in self.translation)
        return {
            "x_mm": x,
            "y_mm": y,
            "z_mm": z,
            "roll_deg": float(np.degrees(roll)),
            "pitch_deg": float(np.degrees(pitch)),
            "yaw_deg": float(np.degrees(yaw)),
        }


def transform_from_dict(data: Mapping[str, object], *, where: str = "pose") -> Transform:
    """Parse the ``{x_mm, ..., yaw_deg}`` form; missing keys are zero, unknown keys an error.

    Parameters
    ----------
    data : mapping
        Keys from ``POSE_KEYS``; values in mm and degrees.
    where : str
        Where the mapping came from (file and key path), for error messages.

    Raises
    ------
    ValueError
        If ``data`` is not a mapping, has unknown keys or non-finite / non-numeric values.
    """
    if not isinstance(data, Mapping):
        raise ValueError(f"{where}: expected a mapping with keys {', '.join(POSE_KEYS)}, got {type(data).__name__}")
    unknown = sorted(set(data) - set(POSE_KEYS))
    if unknown:
        raise ValueError(f"{where}: unknown key(s) {unknown}; expected some of {', '.join(POSE_KEYS)}")
    values = {}
    for key in POSE_KEYS:
        value = data.get(key, 0.0)
        if isinstance(value, bool) or not isinstance(value, int | float) or not np.isfinite(value):
            raise ValueError(f"{where}.{key}: expected a finite number, got {value!r}")
        values[key] = float(value)
    return Transform.from_euler(
        x=values["x_mm"] / 1000.0,
        y=values["y_mm"] / 1000.0,
        z=values["z_mm"] / 1000.0,
        roll=np.radians(values["roll_deg"]),
        pitch=np.radians(values["pitch_deg"]),
        yaw=np.radians(values["yaw_deg"]),
    )


def quaternion_from_matrix(R: ArrayLike) -> NDArray[np.float64]:
    """Unit quaternion ``(x, y, z, w)`` of a rotation matrix (3, 3), ``w >= 0`` (Foxglove's order).

    Shepperd's method: start from the largest of the four squared components, so that no division
    by a small number loses precision near 180 degrees.
    """
    return _quaternion_from_rotation(check_rotation(R))


def _quaternion_from_rotation(R: NDArray[np.float64]) -> NDArray[np.float64]:
    """:func:`quaternion_from_matrix` of a rotation already checked (a :class:`Transform`'s: the recorder
    logs one every control cycle, and checking it again was 10 of the 16 us)."""
    trace = np.trace(R)
    squares = np.array([1 + 2 * R[0, 0] - trace, 1 + 2 * R[1, 1] - trace, 1 + 2 * R[2, 2] - trace, 1 + trace])
    k = int(np.argmax(squares))
    q = np.empty(4)
    q[k] = np.sqrt(squares[k]) / 2
    off = np.array([R[2, 1] - R[1, 2], R[0, 2] - R[2, 0], R[1, 0] - R[0, 1]])  # 4w * (x, y, z)
    sym = np.array([R[1, 0] + R[0, 1], R[0, 2] + R[2, 0], R[2, 1] + R[1, 2]])  # 4 * (xy, xz, yz)
    if k == 3:
        q[:3] = off / (4 * q[3])
    else:
        q[3] = off[k] / (4 * q[k])
        for i in {0, 1, 2} - {k}:
            q[i] = sym[i + k - 1] / (4 * q[k])  # the pair (i, k) sits at index i + k - 1 of sym
    return q if q[3] >= 0 else -q
