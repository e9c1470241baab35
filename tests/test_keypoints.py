"""Keypoint selectors (plugins/keypoints): geometry, agreement with Open3D, budget, errors."""

from __future__ import annotations

import numpy as np
import pytest
from lwbench_plugins.keypoints import ISS, SIFT3D, Harris3D, KeypointError
from lwbench_plugins.keypoints._base import MIN_POINTS, voxel_firsts
from lwbench_plugins.keypoints._geometry import eigvals_sym6, eigvec_sym6, hybrid_neighbourhood
from lwbench_plugins.keypoints.iss import iss_response
from scipy.spatial import cKDTree

from lwbench import Frame, LwbenchError, get_sensor, top_k

SELECTORS = (Harris3D, ISS, SIFT3D)
KITTI = "kitti00_frames0-1/000000.bin"


def frame(points: np.ndarray, index: int = 0) -> Frame:
    return Frame(points=np.asarray(points, dtype=np.float32), sensor=get_sensor("hdl64e"), index=index)


def cube_surface(n: int, side: float, noise: float, seed: int = 0) -> tuple[np.ndarray, np.ndarray]:
    """``n`` points uniformly on the surface of an axis-aligned cube, and its 8 corners."""
    rng = np.random.default_rng(seed)
    face = rng.integers(0, 6, n)
    uv = rng.random((n, 2)) * side
    pts = np.empty((n, 3))
    axis, high = face % 3, face // 3
    for a in range(3):
        m = axis == a
        others = [b for b in range(3) if b != a]
        pts[m, a] = high[m] * side
        pts[m, others[0]], pts[m, others[1]] = uv[m, 0], uv[m, 1]
    origin = np.array([12.0, -7.0, 1.5])  # away from the sensor origin, as in a scan
    pts += origin + rng.normal(scale=noise, size=pts.shape)
    corners = origin + side * np.array([[i, j, k] for i in (0, 1) for j in (0, 1) for k in (0, 1)], float)
    return pts.astype(np.float32), corners


def grid_cube(side: float, step: float, noise: float, seed: int = 0) -> tuple[np.ndarray, np.ndarray]:
    """A cube's surface sampled on a regular grid (as a scanner samples it), and its 8 corners."""
    g = np.arange(step / 2, side, step)
    u, v = (a.ravel() for a in np.meshgrid(g, g))
    faces = []
    for a in range(3):
        others = [b for b in range(3) if b != a]
        for h in (0.0, side):
            f = np.empty((len(u), 3))
            f[:, a], f[:, others[0]], f[:, others[1]] = h, u, v
            faces.append(f)
    origin = np.array([12.0, -7.0, 1.5])
    pts = np.concatenate(faces) + origin + np.random.default_rng(seed).normal(scale=noise, size=(6 * len(u), 3))
    corners = origin + side * np.array([[i, j, k] for i in (0, 1) for j in (0, 1) for k in (0, 1)], float)
    return pts.astype(np.float32), corners


@pytest.fixture(scope="module")
def kitti_quarter(real_data) -> np.ndarray:
    """Every 6th point of the real KITTI frame (~21k points): real structure, fast tests."""
    pts = np.fromfile(real_data / KITTI, np.float32).reshape(-1, 3)
    return pts[::6].copy()


# -- closed-form eigen solver ------------------------------------------------------------------
def test_closed_form_eigen_matches_numpy():
    rng = np.random.default_rng(1)
    a = rng.normal(size=(500, 3, 3))
    a = a @ a.transpose(0, 2, 1)
    a[:50] = np.diag([2.0, 2.0, 5.0])  # repeated eigenvalue: the vector of 2 is undefined
    m = np.stack([a[:, 0, 0], a[:, 0, 1], a[:, 0, 2], a[:, 1, 1], a[:, 1, 2], a[:, 2, 2]])
    lam = eigvals_sym6(m)
    w, v = np.linalg.eigh(a)
    np.testing.assert_allclose(lam.T, w, atol=1e-9)
    vec, ok = eigvec_sym6(m, lam[0])
    assert not ok[:50].any() and ok[50:].all()
    np.testing.assert_allclose(np.abs((vec.T[50:] * v[50:, :, 0]).sum(axis=1)), 1.0, atol=1e-9)


# -- geometry ------------------------------------------------------------------------------------
@pytest.mark.parametrize(
    ("selector", "step"),
    [
        (Harris3D(points=8, radius=0.3), 0.04),
        (Harris3D(points=8, radius=0.3, max_nn=300), 0.05),  # no ball capped (largest: 267)
        # ISS needs more of its ball than max_nn=16 holds on a cube sampled every 4 cm
        (ISS(points=8, salient_radius=0.3, non_max_radius=0.4, max_nn=48), 0.04),
        (ISS(points=8, salient_radius=0.3, non_max_radius=0.4, max_nn=300), 0.05),
    ],
    ids=["harris3d", "harris3d-uncapped", "iss", "iss-uncapped"],
)
def test_finds_the_eight_corners_of_a_cube(selector, step):
    pts, corners = grid_cube(side=2.0, step=step, noise=0.002)  # 15,000 / 9,600 points
    idx = selector.select(frame(pts))
    assert len(idx) == 8
    dist, which = cKDTree(pts[idx]).query(corners)
    assert dist.max() < 0.25, f"corner missed by {dist.max():.3f} m"
    assert len(set(which.tolist())) == 8  # one keypoint per corner


def test_harris_flat_and_edge_points_score_below_corners():
    pts, corners = grid_cube(side=2.0, step=0.04, noise=0.002)
    tier, score = Harris3D(radius=0.3).rank(pts)
    near_corner = cKDTree(corners).query(pts)[0] < 0.3
    # PCL's response of an ideal 3-plane corner is 1/27, of a plane or an edge 0
    assert score[near_corner].max() > 0.01
    assert score[near_corner].max() > 5 * np.percentile(score[~near_corner], 99)
    assert (tier == 0).sum() < 200  # NMS leaves few keypoints on a cube


def bumpy_ground() -> tuple[np.ndarray, np.ndarray]:
    """A 10 m x 10 m ground grid (0.1 m) with four Gaussian bumps (sigma 0.4 m, 0.5 m high)."""
    g = np.arange(0.0, 10.0, 0.1)
    x, y = np.meshgrid(g, g)
    centres = np.array([[2.5, 2.5], [7.5, 2.5], [2.5, 7.5], [7.0, 7.0]])
    z = sum(0.5 * np.exp(-((x - cx) ** 2 + (y - cy) ** 2) / (2 * 0.4**2)) for cx, cy in centres)
    return np.stack([x.ravel(), y.ravel(), z.ravel()], axis=1), centres


@pytest.mark.parametrize(
    "selector",
    [
        SIFT3D(points=4, min_scale=0.2, n_octaves=3),  # blobs of z
        # the bumps are also blobs of curvature; the grid step 0.1 m sets the finest scale
        SIFT3D(points=4, field="curvature", min_scale=0.1, n_octaves=3, curvature_radius=0.3),
    ],
    ids=["z", "curvature"],
)
def test_sift_responds_at_blobs_of_the_field(selector):
    pts, centres = bumpy_ground()
    idx = selector.select(frame(pts))
    dist, which = cKDTree(pts[idx, :2]).query(centres)
    assert dist.max() < 0.35, f"blob centre missed by {dist.max():.2f} m"
    assert len(set(which.tolist())) == 4
    tier, _ = selector.rank(pts)
    assert (tier == 0).sum() < 150  # extrema are rare: 10,000 points, a few dozen extrema


def test_sift_z_field_ignores_a_flat_ground():
    pts, _ = bumpy_ground()
    pts[:, 2] = 0.0
    _, score = SIFT3D(min_scale=0.2, n_octaves=3).rank(pts)
    assert np.abs(score).max() < 1e-9  # no height structure: no DoG response anywhere


# -- agreement with Open3D -------------------------------------------------------------------
def test_iss_agrees_with_open3d_exactly_when_neighbourhoods_are_not_capped():
    o3d = pytest.importorskip("open3d")
    pts, _ = cube_surface(6_000, side=1.0, noise=0.003)
    cloud = o3d.geometry.PointCloud(o3d.utility.Vector3dVector(pts.astype(np.float64)))
    ref = np.asarray(
        o3d.geometry.keypoint.compute_iss_keypoints(cloud, salient_radius=0.15, non_max_radius=0.1).points
    )
    d, ref_idx = cKDTree(pts).query(ref)  # Open3D returns points, not indices
    assert d.max() == 0.0
    assert hybrid_neighbourhood(pts, 128, 0.15).count.max() < 128  # no ball is capped
    _, _, keypoint, _, _ = iss_response(pts, 0.15, 0.1, max_nn=128)
    ours = np.flatnonzero(keypoint)
    assert len(ours) > 20
    assert set(ours.tolist()) == set(ref_idx.tolist())


# -- budget, determinism, errors --------------------------------------------------------------
@pytest.mark.parametrize("cls", SELECTORS, ids=lambda c: c.name)
@pytest.mark.parametrize("budget", [{"points": 2_000}, {"ratio": 0.08}, {"ratio": 0.5}])
def test_budget_is_met_on_a_real_scan(cls, budget, kitti_quarter):
    n = len(kitti_quarter)
    want = budget.get("points") or round(budget["ratio"] * n)
    idx = cls(**budget).select(frame(kitti_quarter))
    assert abs(len(idx) - want) <= 0.02 * want
    assert len(np.unique(idx)) == len(idx) and idx.min() >= 0 and idx.max() < n


def test_voxel_thinning_detects_on_one_point_per_voxel(kitti_quarter):
    f = frame(kitti_quarter)
    reps = voxel_firsts(f.points, 0.5)
    assert 1_000 < len(reps) < len(f) // 2
    idx = Harris3D(points=500, voxel=0.5).select(f)
    assert set(idx.tolist()) <= set(reps.tolist())  # budget below the voxel count: only detections
    over = Harris3D(ratio=0.95, voxel=0.5).select(f)  # above it: every detection, then the rest
    assert len(over) == round(0.95 * len(f)) and set(reps.tolist()) <= set(over.tolist())


@pytest.mark.parametrize("cls", SELECTORS, ids=lambda c: c.name)
def test_budget_is_met_on_a_vlp16_scan(cls, vlp16_frame):
    want = round(0.1 * len(vlp16_frame))
    assert abs(len(cls(ratio=0.1).select(vlp16_frame)) - want) <= 0.02 * want


@pytest.mark.parametrize("cls", SELECTORS, ids=lambda c: c.name)
def test_deterministic_and_round_trips(cls, kitti_quarter):
    f = frame(kitti_quarter[:8_000])
    a, b = cls(points=500).select(f), cls(points=500).select(f)
    np.testing.assert_array_equal(a, b)
    codec = cls(points=500)
    decoded = cls().decode(codec.encode(f))
    np.testing.assert_array_equal(decoded, f.points[a])


@pytest.mark.parametrize("cls", SELECTORS, ids=lambda c: c.name)
@pytest.mark.parametrize("n", [0, 1, MIN_POINTS - 1])
def test_empty_or_tiny_scan_is_a_clear_error(cls, n):
    pts = np.random.default_rng(0).random((n, 3))
    with pytest.raises(KeypointError, match="at least") as err:
        cls(points=5).select(frame(pts))
    assert isinstance(err.value, LwbenchError) and isinstance(err.value, ValueError)


@pytest.mark.parametrize("cls", SELECTORS, ids=lambda c: c.name)
def test_small_scans_and_degenerate_geometry_still_meet_the_budget(cls):
    rng = np.random.default_rng(3)
    line = np.zeros((MIN_POINTS, 3))
    line[:, 0] = np.arange(MIN_POINTS)  # collinear: no normals, no scatter
    for pts in (rng.random((MIN_POINTS, 3)), line, np.ones((50, 3))):
        idx = cls(points=5).select(frame(pts))
        assert len(idx) == 5 and len(np.unique(idx)) == 5


def test_top_k_orders_by_tier_then_score_then_index():
    tier = np.array([1, 0, 0, 2, 1, 0])
    score = np.array([9.0, 1.0, 3.0, 100.0, np.nan, 1.0])
    np.testing.assert_array_equal(top_k(tier, score, 2), [1, 2])  # tier 0, best score, lower index
    np.testing.assert_array_equal(top_k(tier, score, 4), [0, 1, 2, 5])
    np.testing.assert_array_equal(top_k(tier, score, 5), [0, 1, 2, 4, 5])  # NaN ranks last in its tier


def test_registered_through_the_entry_point():
    from importlib.metadata import entry_points

    (ep,) = [e for e in entry_points(group="lwbench") if e.name == "keypoints"]
    codecs = ep.load().lwbench_codecs()
    assert {c.name for c in codecs} == {"harris3d", "iss", "sift3d"}
    assert all(c.describe()["kind"] == "selection" for c in codecs)
