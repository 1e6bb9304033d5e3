"""Rigid-motion conventions, written once.

Frames
------
* **Camera frame** (OpenCV): x right, y down, z forward; metres.
* **World frame** (simulator): X east, Y north, Z up; metres. The agent moves on the plane Z = 0
  and its heading ``yaw`` (radians) is measured counter-clockwise from +X, seen from above.
* A pose ``T_a_b`` is a 4x4 homogeneous matrix mapping points in frame *b* into frame *a*.
  ``Estimate.transform`` is ``T_prev_cur``: the pose of the current camera in the previous one.

Planar motion (the paper's ``(dx, dz, dyaw)``)
----------------------------------------------
Expressed in the *previous* camera/agent frame:

* ``dx``  lateral translation, metres, positive to the **right** (camera +x);
* ``dz``  forward translation, metres, positive **forward** (camera +z);
* ``dyaw`` rotation about the up axis (camera -y), radians, positive = **turn left**
  (counter-clockwise seen from above), wrapped to (-pi, pi].

So a noiseless ``move_forward`` is (0, 0.25, 0) and ``turn_left`` is (0, 0, +pi/6).
"""

from __future__ import annotations

import numpy as np

__all__ = [
    "agent_from_camera_pose",
    "camera_pose_from_agent",
    "integrate",
    "invert",
    "planar_to_transform",
    "rotation_angle",
    "transform_to_planar",
    "wrap_angle",
]


def wrap_angle(a: np.ndarray | float) -> np.ndarray | float:
    """Wrap angles (radians) to (-pi, pi]."""
    w = np.mod(np.asarray(a, dtype=np.float64) + np.pi, 2.0 * np.pi) - np.pi
    w = np.where(w == -np.pi, np.pi, w)
    return float(w) if np.ndim(w) == 0 else w


def planar_to_transform(dx: float, dz: float, dyaw: float) -> np.ndarray:
    """4x4 ``T_prev_cur`` (camera axes) of a planar motion; see the module docstring for signs."""
    c, s = np.cos(dyaw), np.sin(dyaw)
    T = np.eye(4)
    # Turning left by dyaw rotates the forward axis (+z) towards -x: the new z axis is (-s, 0, c).
    T[:3, :3] = [[c, 0.0, -s], [0.0, 1.0, 0.0], [s, 0.0, c]]
    T[0, 3], T[2, 3] = dx, dz
    return T


def transform_to_planar(T: np.ndarray) -> np.ndarray:
    """``(dx, dz, dyaw)`` (m, m, rad) of a 4x4 ``T_prev_cur``; out-of-plane parts are dropped."""
    T = np.asarray(T, dtype=np.float64)
    return np.array([T[0, 3], T[2, 3], np.arctan2(-T[0, 2], T[2, 2])])


def invert(T: np.ndarray) -> np.ndarray:
    """Inverse of a rigid 4x4 transform (or a stack of them, shape (..., 4, 4))."""
    T = np.asarray(T, dtype=np.float64)
    R = np.swapaxes(T[..., :3, :3], -1, -2)
    out = np.zeros_like(T)
    out[..., :3, :3] = R
    out[..., :3, 3] = -np.einsum("...ij,...j->...i", R, T[..., :3, 3])
    out[..., 3, 3] = 1.0
    return out


# World <- camera rotation at yaw 0: camera z (forward) = world +X, camera x (right) = world -Y,
# camera y (down) = world -Z.
_R_WORLD_CAM0 = np.array([[0.0, 0.0, 1.0], [-1.0, 0.0, 0.0], [0.0, -1.0, 0.0]])


def camera_pose_from_agent(x: float, y: float, yaw: float, height: float) -> np.ndarray:
    """``T_world_cam`` (4x4) of a level camera at world (x, y, height) with heading ``yaw`` (rad)."""
    c, s = np.cos(yaw), np.sin(yaw)
    Rz = np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])
    T = np.eye(4)
    T[:3, :3] = Rz @ _R_WORLD_CAM0
    T[:3, 3] = (x, y, height)
    return T


def agent_from_camera_pose(T_world_cam: np.ndarray) -> tuple[float, float, float]:
    """Inverse of :func:`camera_pose_from_agent` for a level camera: (x m, y m, yaw rad)."""
    fwd = T_world_cam[:3, 2]
    return float(T_world_cam[0, 3]), float(T_world_cam[1, 3]), float(np.arctan2(fwd[1], fwd[0]))


def integrate(relative: np.ndarray, start: np.ndarray | None = None) -> np.ndarray:
    """Chain relative transforms ``T_{t-1,t}`` (N, 4, 4) into absolute poses (N + 1, 4, 4).

    ``start`` is the first absolute pose (identity by default).
    """
    relative = np.asarray(relative, dtype=np.float64).reshape(-1, 4, 4)
    poses = np.empty((len(relative) + 1, 4, 4))
    poses[0] = np.eye(4) if start is None else start
    for i, T in enumerate(relative):
        poses[i + 1] = poses[i] @ T
    return poses


def rotation_angle(R: np.ndarray) -> np.ndarray | float:
    """Geodesic angle (radians, in [0, pi]) of rotation matrices (..., 3, 3).

    ``atan2(|vee(R - R^T)| / 2, (trace R - 1) / 2)``: the same angle as ``acos((tr - 1) / 2)``
    (KITTI devkit) and as the norm of the SO(3) log (evo), without ``acos``'s loss of precision
    for small angles.
    """
    R = np.asarray(R, dtype=np.float64)
    cos = (np.trace(R, axis1=-2, axis2=-1) - 1.0) / 2.0
    axis = np.stack([R[..., 2, 1] - R[..., 1, 2], R[..., 0, 2] - R[..., 2, 0], R[..., 1, 0] - R[..., 0, 1]], -1)
    a = np.arctan2(np.linalg.norm(axis, axis=-1) / 2.0, cos)
    return float(a) if np.ndim(a) == 0 else a
