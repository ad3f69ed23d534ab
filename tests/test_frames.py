"""vnav.frames: the convention rotations and the frame tree."""

from __future__ import annotations

import numpy as np
import pytest
from helpers import PROPERTY_SETTINGS, transforms
from hypothesis import given
from hypothesis import strategies as st

from vnav import frames, se3, so3

SETTINGS = PROPERTY_SETTINGS
T_OK = se3.make(so3.rot_z(0.3), [1.0, 2.0, 3.0])

ALL = {
    "R_FLU_RDF": frames.R_FLU_RDF,
    "R_RDF_FLU": frames.R_RDF_FLU,
    "R_GLC_RDF": frames.R_GLC_RDF,
    "R_RDF_GLC": frames.R_RDF_GLC,
    "R_ENU_NED": frames.R_ENU_NED,
    "R_NED_ENU": frames.R_NED_ENU,
    "R_FLU_FRD": frames.R_FLU_FRD,
    "R_FRD_FLU": frames.R_FRD_FLU,
}


@pytest.mark.parametrize("name", sorted(ALL))
def test_constants_are_read_only_rotations(name):
    R = ALL[name]
    assert R.dtype == np.float64 and R.shape == (3, 3)
    assert so3.is_rotation(R)
    with pytest.raises(ValueError, match="read-only"):
        R[0, 0] = 2.0


def test_pairs_are_transposes():
    np.testing.assert_array_equal(frames.R_RDF_FLU, frames.R_FLU_RDF.T)
    np.testing.assert_array_equal(frames.R_RDF_GLC, frames.R_GLC_RDF)  # self-inverse
    np.testing.assert_array_equal(frames.R_GLC_RDF, np.diag([1.0, -1.0, -1.0]))
    np.testing.assert_array_equal(frames.R_NED_ENU, frames.R_ENU_NED.T)
    np.testing.assert_array_equal(frames.R_FRD_FLU, frames.R_FLU_FRD.T)


def test_optical_axes_in_body():
    # camera z forward -> body x; camera x right -> body -y; camera y down -> body -z.
    np.testing.assert_array_equal(frames.R_FLU_RDF @ [0, 0, 1], [1, 0, 0])
    np.testing.assert_array_equal(frames.R_FLU_RDF @ [1, 0, 0], [0, -1, 0])
    np.testing.assert_array_equal(frames.R_FLU_RDF @ [0, 1, 0], [0, 0, -1])
    # OpenGL camera looks along -z with y up: optical forward is glc -z, optical down is glc -y.
    np.testing.assert_array_equal(frames.R_GLC_RDF @ [0, 0, 1], [0, 0, -1])
    np.testing.assert_array_equal(frames.R_GLC_RDF @ [0, 1, 0], [0, -1, 0])
    # NED north = ENU y, NED down = ENU -z.
    np.testing.assert_array_equal(frames.R_ENU_NED @ [1, 0, 0], [0, 1, 0])
    np.testing.assert_array_equal(frames.R_ENU_NED @ [0, 0, 1], [0, 0, -1])


def test_mount_rotation_tips_the_optical_axis_down():
    np.testing.assert_array_equal(frames.mount_rotation(0.0), frames.R_FLU_RDF)
    pitch = np.radians(30)
    R_b_c = frames.mount_rotation(pitch)
    forward_b = R_b_c @ [0.0, 0.0, 1.0]  # optical axis in the body
    np.testing.assert_allclose(forward_b, [np.cos(pitch), 0.0, -np.sin(pitch)], atol=1e-15)
    np.testing.assert_allclose(R_b_c @ [1.0, 0.0, 0.0], [0.0, -1.0, 0.0], atol=1e-15)
    down = frames.mount_rotation(np.pi / 2) @ [0.0, 0.0, 1.0]
    np.testing.assert_allclose(down, [0.0, 0.0, -1.0], atol=1e-15)


def test_frame_tree_moving_body_and_properties():
    tree = frames.FrameTree()
    T_b_c = se3.make(frames.mount_rotation(0.2), [0.1, 0.0, -0.05])
    tree.add("world", "body", np.eye(4))
    tree.add("body", "camera", T_b_c)
    assert tree.frames == ("world", "body", "camera")
    assert "camera" in tree and "lidar" not in tree
    assert tree.parent("camera") == "body" and tree.parent("world") is None
    np.testing.assert_array_equal(tree.lookup("camera", "camera"), np.eye(4))
    for yaw in (0.0, 1.0, -2.0):
        T_w_b = se3.make(so3.rot_z(yaw), [yaw, 2.0, 10.0])
        tree.set("world", "body", T_w_b)
        np.testing.assert_allclose(tree.lookup("world", "camera"), T_w_b @ T_b_c, atol=1e-14)
    # The stored edge is a copy: mutating the caller's array changes nothing.
    T = se3.make(np.eye(3), [1.0, 0.0, 0.0])
    tree.add("world", "cone", T)
    T[0, 3] = 99.0
    assert tree.lookup("world", "cone")[0, 3] == 1.0
    # Joining two trees by giving a root a parent is allowed.
    tree.add("map", "odom", np.eye(4))
    tree.add("odom", "world", se3.make(np.eye(3), [0.0, 0.0, 1.0]))
    np.testing.assert_allclose(tree.lookup("map", "cone")[:3, 3], [1.0, 0.0, 1.0], atol=1e-15)


@SETTINGS
@given(st.lists(transforms(), min_size=4, max_size=4), st.data())
def test_frame_tree_lookup_equals_manual_composition(Ts, data):
    # world -> body -> camera, and world -> landmark; body -> imu, all random.
    T_w_b, T_b_c, T_w_l, T_b_i = Ts
    tree = frames.FrameTree()
    tree.add("world", "body", T_w_b)
    tree.add("body", "camera", T_b_c)
    tree.add("world", "landmark", T_w_l)
    tree.add("body", "imu", T_b_i)
    manual = {
        "world": np.eye(4),
        "body": T_w_b,
        "camera": T_w_b @ T_b_c,
        "landmark": T_w_l,
        "imu": T_w_b @ T_b_i,
    }  # T_w_x
    a = data.draw(st.sampled_from(sorted(manual)))
    b = data.draw(st.sampled_from(sorted(manual)))
    expected = se3.invert(manual[a]) @ manual[b]
    np.testing.assert_allclose(tree.lookup(a, b), expected, atol=1e-10)
    np.testing.assert_allclose(tree.lookup(a, b) @ tree.lookup(b, a), np.eye(4), atol=1e-10)


# ------------------------------------------------------------------------------- bad input
# Bad input raises ValueError with a message that names the problem (docs/CONVENTIONS.md, "Errors").


def test_bottom_row_not_0001():
    T = T_OK.copy()
    T[3] = [0.0, 0.0, 1.0, 1.0]
    tree = frames.FrameTree()
    with pytest.raises(ValueError, match=r"T_world_body must have bottom row"):
        tree.add("world", "body", T)


def test_frame_tree_errors():
    tree = frames.FrameTree()
    tree.add("world", "body", T_OK)
    tree.add("body", "camera", T_OK)
    tree.add("map", "odom", T_OK)
    with pytest.raises(ValueError, match=r"unknown frame 'lidar'; known frames: 'world', 'body'"):
        tree.lookup("world", "lidar")
    with pytest.raises(ValueError, match=r"frames 'camera' and 'odom' are not connected"):
        tree.lookup("camera", "odom")
    with pytest.raises(ValueError, match=r"frame 'camera' already has parent 'body'"):
        tree.add("world", "camera", T_OK)
    with pytest.raises(ValueError, match=r"would close a cycle: 'world' is already an ancestor"):
        tree.add("camera", "world", T_OK)
    with pytest.raises(ValueError, match=r"cannot be its own parent"):
        tree.add("body", "body", T_OK)
    with pytest.raises(ValueError, match=r"no edge 'world' -> 'camera' to set"):
        tree.set("world", "camera", T_OK)
    with pytest.raises(ValueError, match=r"non-empty str"):
        tree.add("", "x", T_OK)
