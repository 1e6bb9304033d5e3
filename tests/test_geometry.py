import numpy as np
import pytest

from odolab.core.geometry import (
    agent_from_camera_pose,
    camera_pose_from_agent,
    integrate,
    invert,
    planar_to_transform,
    transform_to_planar,
    wrap_angle,
)


@pytest.mark.parametrize("dx,dz,dyaw", [(0.0, 0.25, 0.0), (0.02, -0.1, 0.5236), (-0.3, 0.0, -3.0)])
def test_planar_round_trip(dx, dz, dyaw):
    assert transform_to_planar(planar_to_transform(dx, dz, dyaw)) == pytest.approx([dx, dz, dyaw])


def test_turn_left_is_positive_yaw_and_counter_clockwise_in_world():
    # Agent at the origin facing +X turns left by 30 deg: it now faces between +X and +Y.
    before = camera_pose_from_agent(0.0, 0.0, 0.0, 0.88)
    after = camera_pose_from_agent(0.0, 0.0, np.radians(30), 0.88)
    rel = invert(before) @ after
    assert transform_to_planar(rel) == pytest.approx([0.0, 0.0, np.radians(30)])
    assert after[:3, 2] @ np.array([0.0, 1.0, 0.0]) > 0  # camera z (forward) tilted to +Y (left)


def test_forward_and_right_in_camera_frame():
    before = camera_pose_from_agent(1.0, 2.0, np.pi / 2, 0.88)  # facing +Y
    moved = camera_pose_from_agent(1.1, 2.25, np.pi / 2, 0.88)  # 0.25 forward, 0.1 to the right (+X)
    dx, dz, dyaw = transform_to_planar(invert(before) @ moved)
    assert (dx, dz, dyaw) == pytest.approx((0.1, 0.25, 0.0))
    assert agent_from_camera_pose(moved) == pytest.approx((1.1, 2.25, np.pi / 2))


def test_camera_axes_are_opencv_level():
    T = camera_pose_from_agent(0, 0, 0.7, 0.88)
    R = T[:3, :3]
    assert R @ np.array([0, 1, 0]) == pytest.approx([0, 0, -1])  # camera y points down
    assert np.linalg.det(R) == pytest.approx(1.0)
    assert T[2, 3] == pytest.approx(0.88)


def test_integrate_and_invert():
    steps = np.stack([planar_to_transform(0.0, 0.25, np.pi / 2)] * 4)
    poses = integrate(steps)
    assert poses.shape == (5, 4, 4)
    assert np.allclose(poses[-1], np.eye(4), atol=1e-12)  # a square closes the loop
    assert np.allclose(invert(poses[2]) @ poses[2], np.eye(4))


def test_wrap_angle():
    assert wrap_angle(3 * np.pi) == pytest.approx(np.pi)
    assert wrap_angle(-np.pi) == pytest.approx(np.pi)
    assert np.allclose(wrap_angle(np.array([0.1, 2 * np.pi + 0.1])), [0.1, 0.1])
