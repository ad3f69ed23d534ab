"""vnav.se3: rigid transforms as 4x4 matrices; against SciPy's RigidTransform.

The group laws SE(3) shares with SO(3) and the unit quaternions are in test_group_laws.py.
"""

from __future__ import annotations

import numpy as np
import pytest
from helpers import PROPERTY_SETTINGS, rotation_vectors, transforms, translations
from hypothesis import given
from hypothesis import strategies as st

from vnav import se3, so3

SETTINGS = PROPERTY_SETTINGS
R_OK = so3.rot_z(0.3)
T_OK = se3.make(R_OK, [1.0, 2.0, 3.0])


# ------------------------------------------------------------------------------- unit tests


def test_batched_shapes():
    rng = np.random.default_rng(1)
    R = so3.exp(rng.normal(size=(4, 5, 3)))
    assert se3.make(R, np.zeros(3)).shape == (4, 5, 4, 4)
    assert se3.invert(se3.make(R, np.zeros(3))).shape == (4, 5, 4, 4)
    p = rng.normal(size=(1000, 3))
    assert se3.apply(se3.make(R[0, 0], [1, 2, 3]), p).shape == (1000, 3)


def test_se3_invert_is_closed_form_exact():
    T = se3.make(so3.exp([0.4, -1.2, 2.9]), [100.0, -3.0, 0.25])
    T_inv = se3.invert(T)
    assert T_inv[3].tolist() == [0.0, 0.0, 0.0, 1.0]  # exact bottom row, unlike a general inverse
    np.testing.assert_array_equal(T_inv[:3, :3], T[:3, :3].T)
    np.testing.assert_allclose(T_inv @ T, np.eye(4), atol=1e-13)


def test_apply_nan_points_pass_through():
    T = se3.make(so3.rot_z(0.5), [1.0, 2.0, 3.0])
    p = np.array([[1.0, 2.0, 3.0], [np.nan, np.nan, np.nan]])
    out = se3.apply(T, p)
    assert np.all(np.isfinite(out[0])) and np.all(np.isnan(out[1]))
    # The chunked fast path agrees with the plain formula at every length around its blocks.
    rng = np.random.default_rng(3)
    for n in (1, 511, 512, 513, 131071, 131073):
        p = rng.normal(size=(n, 3))
        np.testing.assert_allclose(se3.apply(T, p), p @ T[:3, :3].T + T[:3, 3], atol=1e-14)


# ---------------------------------------------------------------------------- properties


@SETTINGS
@given(transforms(), st.lists(translations, min_size=1, max_size=20))
def test_apply_is_homogeneous_multiplication(T, points):
    p = np.array(points)
    p_h = np.column_stack([p, np.ones(len(p))])
    np.testing.assert_allclose(se3.apply(T, p), (T @ p_h.T).T[:, :3], atol=1e-12)
    np.testing.assert_allclose(se3.apply(se3.invert(T), se3.apply(T, p)), p, atol=1e-11)
    np.testing.assert_allclose(se3.apply(T, p[0]), se3.apply(T, p)[0], atol=1e-12)


# ------------------------------------------------------------ independent implementations


def test_se3_apply_matches_scipy_rigid_transform(rng):
    from scipy.spatial.transform import RigidTransform

    for v, t in zip(rotation_vectors(rng, 50), rng.uniform(-5, 5, (50, 3)), strict=True):
        T = se3.make(so3.exp(v), t)
        p = rng.uniform(-10, 10, (1000, 3))
        rigid = RigidTransform.from_matrix(T)
        np.testing.assert_allclose(se3.apply(T, p), rigid.apply(p), atol=1e-13)
        np.testing.assert_allclose(se3.invert(T), rigid.inv().as_matrix(), atol=1e-14)


# ------------------------------------------------------------------------------- bad input
# Bad input raises ValueError with a message that names the problem (docs/CONVENTIONS.md, "Errors").


@pytest.mark.parametrize(
    ("call", "match"),
    [
        (lambda: se3.make(R_OK, [1.0, 2.0]), r"t must have shape \(\.\.\., 3\); got shape \(2,\)"),
        (
            lambda: se3.check_transform(np.eye(3)),
            r"T must have shape \(\.\.\., 4, 4\); got shape \(3, 3\)",
        ),
        (
            lambda: se3.apply(T_OK, np.zeros((5, 2))),
            r"p must have shape \(\.\.\., 3\); got shape \(5, 2\)",
        ),
        (lambda: se3.apply(np.stack([T_OK, T_OK]), np.zeros(3)), r"T must have shape \(4, 4\)"),
    ],
)
def test_wrong_shapes(call, match):
    with pytest.raises(ValueError, match=match):
        call()


@pytest.mark.parametrize("bad", [np.nan, np.inf, -np.inf])
def test_nan_and_inf(bad):
    with pytest.raises(ValueError, match=r"t must be finite"):
        se3.make(R_OK, [0.0, bad, 0.0])
    T = T_OK.copy()
    T[0, 3] = bad
    with pytest.raises(ValueError, match=r"T must be finite"):
        se3.invert(T)


def test_not_orthogonal_says_how_far_and_the_determinant():
    with pytest.raises(ValueError, match=r"rotation block T\[:3, :3\] is not a rotation"):
        se3.check_transform(np.diag([1.0, 1.0, 1.1, 1.0]))


def test_reflection_is_rejected():
    with pytest.raises(ValueError, match=r"R is a reflection"):
        se3.make(-np.eye(3), [0.0, 0.0, 0.0])


def test_bottom_row_not_0001():
    T = T_OK.copy()
    T[3] = [0.0, 0.0, 1.0, 1.0]
    with pytest.raises(
        ValueError, match=r"bottom row \[0, 0, 0, 1\].*got bottom row \[0\.?, 0\.?, 1\.?, 1\.?\]"
    ):
        se3.check_transform(T)
    with pytest.raises(ValueError, match=r"bottom row"):
        se3.invert(T)
    with pytest.raises(ValueError, match=r"T_w_b must have bottom row"):
        se3.check_transform(T, name="T_w_b")


def test_float32_transform_is_accepted_and_nan_tolerance_refused():
    from scipy.spatial.transform import Rotation

    T = np.eye(4, dtype=np.float32)
    T[:3, :3] = Rotation.random(random_state=5).as_matrix().astype(np.float32)
    T[:3, 3] = [1.0, 2.0, 3.0]
    assert se3.check_transform(T).dtype == np.float64
    with pytest.raises(ValueError, match="atol must be a finite number >= 0"):
        se3.check_transform(np.eye(4), atol=float("nan"))


def test_float32_transform_shear_names_the_float32_tolerance():
    T = np.eye(4, dtype=np.float32)
    T[0, 1] = 1e-4
    with pytest.raises(
        ValueError,
        match=r"rotation block T_w_b\[:3, :3\] is not .*tolerance 1\.9\d*e-06 for float32",
    ):
        se3.check_transform(T, name="T_w_b")
    for atol in (float("nan"), -1.0, float("inf")):
        with pytest.raises(ValueError, match=r"^atol must be a finite number >= 0"):
            se3.check_transform(T_OK, atol=atol)
    # The plain-float fast path and the full check agree on a float64 pose.
    assert se3.check_transform(T_OK) is T_OK
    np.testing.assert_array_equal(se3.check_pose(T_OK.astype(np.float32)), T_OK.astype(np.float32))


def test_apply_into_a_buffer_is_apply() -> None:
    """``out=``: the same numbers written into the caller's buffer, which is returned; a buffer
    of the wrong shape, dtype or layout, or one overlapping ``p``, is refused."""
    rng = np.random.default_rng(4)
    T = se3.make(so3.exp(rng.normal(size=3)), rng.normal(size=3))
    for shape in ((3,), (5, 3), (2, 7, 3), (20_000, 3)):
        p = rng.normal(size=shape)
        out = np.empty(shape)
        got = se3.apply(T, p, out=out)
        assert got is out
        np.testing.assert_array_equal(out, se3.apply(T, p))
    p = rng.normal(size=(4, 3))
    for bad in (np.empty((4, 3), np.float32), np.empty((3, 4)).T, np.empty((5, 3)), p):
        with pytest.raises(ValueError, match="out must"):
            se3.apply(T, p, out=bad)


def test_apply_kernel_matches_its_lecture_form() -> None:
    """cv2.transform (point sets) and the BLAS path (rotations OpenCV would treat as diagonal)
    against ``_apply_reference``, ``p R^T + t``: every shape, strided input, ``out=``, and a
    NaN or inf coordinate spreading to its whole row exactly as in the reference."""
    rng = np.random.default_rng(8)
    general = se3.make(so3.exp(rng.normal(size=3)), rng.normal(size=3))
    half_turn = se3.make(np.diag([1.0, -1.0, -1.0]), [1.0, 2.0, 3.0])
    for T in (general, half_turn, np.eye(4)):
        for shape in ((1, 3), (2, 3), (1000, 3), (4, 5, 3), (0, 3)):
            p = rng.uniform(-10.0, 10.0, shape)
            np.testing.assert_allclose(se3.apply(T, p), se3._apply_reference(T, p), atol=1e-13)
        p = rng.uniform(-10.0, 10.0, (20, 6))[:, ::2]  # not contiguous
        np.testing.assert_allclose(se3.apply(T, p), se3._apply_reference(T, p), atol=1e-13)
        p = rng.uniform(-10.0, 10.0, (10, 3))
        p[2, 1], p[3, 2], p[4] = np.nan, np.inf, np.nan
        with np.errstate(invalid="ignore"):
            ref = se3._apply_reference(T, p)
        got = se3.apply(T, p, out=np.empty_like(p))
        np.testing.assert_array_equal(np.isnan(got), np.isnan(ref))
        np.testing.assert_allclose(got, ref, atol=1e-13)
    assert not se3._opencv_treats_as_diagonal(general[:3, :3])
    assert se3._opencv_treats_as_diagonal(half_turn[:3, :3])
