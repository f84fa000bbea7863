import math

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from agf.geometry import (
    Transform,
    euler_from_matrix,
    matrix_from_axis_angle,
    matrix_from_euler,
    transform_from_dict,
)

angles = st.floats(-math.pi, math.pi, allow_nan=False)
pitches = st.floats(-1.5, 1.5, allow_nan=False)
coords = st.floats(-5.0, 5.0, allow_nan=False)


@st.composite
def transforms(draw):
    return Transform.from_euler(
        draw(coords), draw(coords), draw(coords), roll=draw(angles), pitch=draw(pitches), yaw=draw(angles)
    )


def test_euler_order_is_z_then_y_then_x():
    # A pure pitch tips the X axis down (front lower) for positive angle about Y with Z up.
    yaw, pitch, roll = 0.3, 0.2, 0.1
    expected = (
        matrix_from_axis_angle(2, yaw) @ matrix_from_axis_angle(1, pitch) @ matrix_from_axis_angle(0, roll)
    )
    np.testing.assert_allclose(matrix_from_euler(yaw, pitch, roll), expected)


def test_yaw_turns_x_towards_y():
    np.testing.assert_allclose(matrix_from_euler(math.pi / 2, 0, 0) @ [1, 0, 0], [0, 1, 0], atol=1e-12)


@given(angles, pitches, angles)
def test_euler_round_trip(yaw, pitch, roll):
    R = matrix_from_euler(yaw, pitch, roll)
    np.testing.assert_allclose(matrix_from_euler(*euler_from_matrix(R)), R, atol=1e-9)


@given(transforms())
def test_inverse_composes_to_identity(T):
    np.testing.assert_allclose((T @ T.inverse()).matrix, np.eye(4), atol=1e-9)
    np.testing.assert_allclose((T.inverse() @ T).matrix, np.eye(4), atol=1e-9)


@settings(max_examples=50)
@given(transforms(), transforms(), transforms())
def test_composition_is_associative(a, b, c):
    np.testing.assert_allclose(((a @ b) @ c).matrix, (a @ (b @ c)).matrix, atol=1e-9)


@given(transforms(), st.lists(st.tuples(coords, coords, coords), min_size=1, max_size=5))
def test_apply_matches_homogeneous_matrix(T, points):
    p = np.array(points)
    homogeneous = np.c_[p, np.ones(len(p))] @ T.matrix.T
    np.testing.assert_allclose(T.apply(p), homogeneous[:, :3], atol=1e-9)


@given(transforms())
def test_dict_round_trip(T):
    back = transform_from_dict(T.to_dict())
    np.testing.assert_allclose(back.matrix, T.matrix, atol=1e-9)


def test_camera_in_fork_maps_camera_origin_to_its_position():
    camera_in_fork = transform_from_dict({"x_mm": -705, "z_mm": 1055})
    np.testing.assert_allclose(camera_in_fork.apply([0.0, 0.0, 0.0]), [-0.705, 0.0, 1.055])


def test_dict_rejects_unknown_key_and_bad_value():
    with pytest.raises(ValueError, match="unknown key"):
        transform_from_dict({"x_m": 1.0})
    with pytest.raises(ValueError, match="finite number"):
        transform_from_dict({"x_mm": float("nan")}, where="scene.yaml: pallet.in_fork")
    with pytest.raises(ValueError, match="finite number"):
        transform_from_dict({"x_mm": "ten"})


def test_transform_rejects_non_rotation():
    with pytest.raises(ValueError, match="orthonormal"):
        Transform(np.diag([1.0, 2.0, 1.0]), np.zeros(3))
    with pytest.raises(ValueError, match="reflection"):
        Transform(np.diag([1.0, 1.0, -1.0]), np.zeros(3))


def test_built_transforms_reject_non_finite_values():
    """from_euler, inverse and composition skip the orthonormality check (their rotations are proper by
    construction) but still refuse NaN, as the full check did."""
    with pytest.raises(ValueError, match="finite"):
        Transform.from_euler(x=float("nan"))
    with pytest.raises(ValueError, match="finite"), np.errstate(invalid="ignore"):
        Transform.from_euler(pitch=float("inf"))
    with pytest.raises(ValueError, match="finite"):
        Transform.from_euler(x=1.0) @ Transform(np.eye(3), np.array([np.nan, 0.0, 0.0]))
