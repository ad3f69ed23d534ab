"""vnav.frames: the convention rotations and the frame tree."""

from __future__ import annotations

import numpy as np
import pytest

from vnav import frames, se3, so3

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
