"""A tracked pose must not hold Open3D's registration result alive: ``res.transformation`` is a
view whose base is the whole result, correspondence set included (a tracking worker grew
~0.45 MB a town scan while the estimates list held them)."""

from __future__ import annotations

import numpy as np
from lwbench_metrics.localization import ICP_PARAMS, _register
from lwbench_metrics.voxel_map import point_cloud, with_normals


def test_register_returns_a_pose_that_owns_its_memory():
    rng = np.random.default_rng(0)
    pts = rng.uniform(-5, 5, size=(4000, 3))
    pts[:, 2] = np.round(pts[:, 2])  # planes, so point-to-plane ICP has normals to use
    target = with_normals(point_cloud(pts), ICP_PARAMS)
    moved = np.eye(4)
    moved[:3, 3] = (0.05, -0.03, 0.0)
    pose, _ = _register(pts, target, moved, ICP_PARAMS)
    assert pose.shape == (4, 4) and pose.flags.owndata and pose.base is None
