"""msta.data.math3d: the quaternion helpers the simulator and the teachers share."""

from __future__ import annotations

import numpy as np

from msta.data.math3d import quat_to_mat, world_to_body, yaw_of, yaw_quat


def test_yaw_round_trip_and_rotation():
    yaw = np.array([0.0, 0.5, -2.0, np.pi / 2])
    q = yaw_quat(yaw)
    np.testing.assert_allclose(yaw_of(q), yaw, atol=1e-12)
    rot = quat_to_mat(q)  # (N, 3, 3) body -> world
    np.testing.assert_allclose(rot @ rot.transpose(0, 2, 1), np.broadcast_to(np.eye(3), rot.shape),
                               atol=1e-12)
    # a quarter turn about z maps body x to world y, and world y back to body x
    np.testing.assert_allclose(rot[3] @ [1.0, 0.0, 0.0], [0.0, 1.0, 0.0], atol=1e-12)
    np.testing.assert_allclose(world_to_body(rot, np.tile([0.0, 1.0, 0.0], (4, 1)))[3],
                               [1.0, 0.0, 0.0], atol=1e-12)
