"""ATE/RPE against evo's numbers (expected.json) plus unit checks of the building blocks."""

from __future__ import annotations

import json

import numpy as np
import pytest

from ferroslam import io, metrics
from ferroslam.trajectory import Trajectory
from ferroslam.transforms import inverse, matrix_to_quat, quat_to_matrix, rotation_angle

# Tolerances from groundtruth/README.md: evo vs. an independent numpy implementation.
TOL = {"tum": dict(rel=1e-9, abs=0.0), "kitti": dict(rel=0.0, abs=1e-6)}
STATS = ("rmse", "mean", "median", "std", "min", "max", "sse")


def _expected(groundtruth_dir):
    return json.loads((groundtruth_dir / "expected.json").read_text())


def _cases():
    # Case names only; the data itself is loaded lazily by the fixture.
    return ["fr2_desk_ORB", "fr1_xyz_rgbdslam", "fr2_desk_ORB_kf_mono", "fr1_xyz_ORB_kf_mono",
            "KITTI_00_ORB"]


_cache: dict = {}


@pytest.fixture(params=_cases())
def case(request, groundtruth_dir):
    name = request.param
    if name not in _cache:
        spec = _expected(groundtruth_dir)["cases"][name]
        read = io.read_tum_trajectory if spec["format"] == "tum" else io.read_kitti_poses
        ref = read(groundtruth_dir / spec["reference"])
        est = read(groundtruth_dir / spec["estimate"])
        _cache[name] = (spec, ref, est)
    return _cache[name]


def _check(got: float, want: float, fmt: str, what: str) -> None:
    tol = TOL[fmt]
    assert got == pytest.approx(want, **tol), f"{what}: got {got!r}, evo {want!r}"


def test_expected_cases_are_all_covered(groundtruth_dir):
    assert sorted(_expected(groundtruth_dir)["cases"]) == sorted(_cases())


def test_file_sizes_and_association(case):
    spec, ref, est = case
    assert len(ref) == spec["poses_reference_file"]
    assert len(est) == spec["poses_estimate_file"]
    i_ref, i_est = metrics.associate(ref.timestamps, est.timestamps, max_diff=0.01)
    assert len(i_ref) == spec["poses_associated"]
    if "first_associated_stamps" in spec:
        assert [est.timestamps[i_est[0]], ref.timestamps[i_ref[0]]] == pytest.approx(
            spec["first_associated_stamps"], abs=1e-9)
        assert [est.timestamps[i_est[-1]], ref.timestamps[i_ref[-1]]] == pytest.approx(
            spec["last_associated_stamps"], abs=1e-9)
    assert ref.subset(i_ref).path_length() == pytest.approx(spec["path_length_reference_m"],
                                                             rel=1e-9)


def test_ate_matches_evo(case):
    spec, ref, est = case
    for align, exp in spec["ate"].items():
        result = metrics.ate(ref, est, align=align)
        assert result.pairs == spec["poses_associated"]
        assert result.unit == "m"
        for k in STATS:
            _check(getattr(result, k), exp["stats"][k], spec["format"], f"ATE {align} {k}")
        if exp["alignment"] is None:
            assert result.alignment is None and result.scale == 1.0
        else:
            a = exp["alignment"]
            assert result.scale == pytest.approx(a["scale"], rel=1e-9)
            np.testing.assert_allclose(result.alignment[:3, :3] / result.scale, a["rotation"],
                                       atol=1e-9)
            np.testing.assert_allclose(result.alignment[:3, 3], a["translation"], atol=1e-8)


def test_rpe_matches_evo(case):
    spec, ref, est = case
    for key, exp in spec["rpe"].items():
        kind, align = key.rsplit("_", 1)
        result = metrics.rpe(ref, est, delta=1, align=align)
        assert result.pairs == exp["pairs"]
        for k in STATS:
            _check(getattr(result, f"{kind}_{k}"), exp["stats"][k], spec["format"],
                   f"RPE {key} {k}")


def _random_poses(rng, n):
    q = rng.normal(size=(n, 4))
    T = np.tile(np.eye(4), (n, 1, 1))
    T[:, :3, :3] = quat_to_matrix(q)
    T[:, :3, 3] = rng.normal(size=(n, 3))
    return T


def test_umeyama_recovers_a_similarity():
    rng = np.random.default_rng(7)
    x = rng.normal(size=(50, 3))
    R = quat_to_matrix(rng.normal(size=4))
    t = np.array([1.0, -2.0, 0.5])
    y = 2.5 * x @ R.T + t
    R_est, t_est, c = metrics.umeyama_alignment(x, y, with_scale=True)
    np.testing.assert_allclose(R_est, R, atol=1e-12)
    np.testing.assert_allclose(t_est, t, atol=1e-12)
    assert c == pytest.approx(2.5, rel=1e-12)
    _, _, c_se3 = metrics.umeyama_alignment(x, y, with_scale=False)
    assert c_se3 == 1.0


def test_umeyama_rejects_bad_input():
    with pytest.raises(ValueError, match="at least 3"):
        metrics.umeyama_alignment(np.zeros((2, 3)), np.zeros((2, 3)))
    with pytest.raises(ValueError, match=r"\(N, 3\)"):
        metrics.umeyama_alignment(np.zeros((5, 3)), np.zeros((4, 3)))
    line = np.outer(np.arange(5.0), [1.0, 0.0, 0.0])
    with pytest.raises(ValueError, match="degenerate"):
        metrics.umeyama_alignment(line, line)


def test_ate_of_transformed_copy_is_zero_and_rpe_invariant():
    rng = np.random.default_rng(3)
    T = _random_poses(rng, 40)
    ref = Trajectory(np.arange(40) * 0.1, T)
    R = quat_to_matrix(np.array([0.1, 0.2, 0.3, 0.9]))
    est = ref.transformed(R, np.array([3.0, 1.0, -2.0]), 0.5)
    assert metrics.ate(ref, est, align="sim3").rmse < 1e-12
    assert metrics.ate(ref, est, align="sim3").scale == pytest.approx(2.0)
    assert metrics.ate(ref, est, align="se3").rmse > 0.1
    assert metrics.rpe(ref, est, align="sim3").trans_rmse < 1e-12
    assert metrics.rpe(ref, est, align="none").rot_deg_rmse < 1e-9


def test_associate_rule():
    ref = np.array([0.0, 1.0, 2.0, 3.0, 4.0])
    est = np.array([0.995, 1.5, 3.01, 3.0101])
    i_ref, i_est = metrics.associate(ref, est, max_diff=0.01)
    # est is shorter: walk over est; 1.5 has no partner; 3.0101 is > 0.01 away from 3.0.
    assert i_est.tolist() == [0, 2] and i_ref.tolist() == [1, 3]
    # exact tie -> the earlier timestamp
    i_ref, i_est = metrics.associate(np.array([1.0, 2.0, 3.0]), np.array([1.5]), max_diff=1.0)
    assert i_ref.tolist() == [0]
    # a pose of the longer trajectory may be used twice
    i_ref, i_est = metrics.associate(np.array([1.0, 1.004]), np.array([1.002, 5.0, 6.0]))
    assert i_ref.tolist() == [0, 1] and i_est.tolist() == [0, 0]
    with pytest.raises(ValueError, match="sorted"):
        metrics.associate(np.array([1.0, 0.0]), np.array([0.0]))


def test_metric_errors_are_clear():
    T = np.tile(np.eye(4), (5, 1, 1))
    T[:, 0, 3] = np.arange(5)
    T[:, 1, 3] = np.arange(5) ** 2
    ref = Trajectory(np.arange(5.0), T)
    far = Trajectory(np.arange(5.0) + 100, T)
    with pytest.raises(ValueError, match="no timestamps"):
        metrics.ate(ref, far)
    with pytest.raises(ValueError, match="align"):
        metrics.ate(ref, ref, align="affine")
    with pytest.raises(ValueError, match="delta"):
        metrics.rpe(ref, ref, delta=0)
    with pytest.raises(ValueError, match="more than delta"):
        metrics.rpe(ref, ref, delta=5)
    with pytest.raises(ValueError, match="empty"):
        metrics.stats(np.zeros(0))
    for metric in (metrics.ate, metrics.rpe, metrics.path_length):
        with pytest.raises(TypeError, match="traj_est must be a ferroslam.Trajectory .* got "
                                            "ndarray"):
            metric(ref, T)
        with pytest.raises(TypeError, match="traj_ref must be a ferroslam.Trajectory .* got list"):
            metric([1, 2, 3], ref)
        with pytest.raises(ValueError, match="max_diff must be a finite number of seconds"):
            metric(ref, ref, max_diff=float("nan"))


def test_trajectory_validation():
    with pytest.raises(ValueError, match="out of order"):
        Trajectory(np.array([0.0, 2.0, 1.0]), np.tile(np.eye(4), (3, 1, 1)))
    with pytest.raises(ValueError, match=r"\(N, 4, 4\)"):
        Trajectory(np.zeros(3), np.zeros((3, 3, 4)))
    with pytest.raises(ValueError, match="NaN"):
        Trajectory(np.array([np.nan]), np.eye(4)[None])


def test_quaternions_round_trip():
    rng = np.random.default_rng(11)
    q = rng.normal(size=(200, 4))
    q /= np.linalg.norm(q, axis=1, keepdims=True)
    q *= np.sign(q[:, 3:])
    R = quat_to_matrix(q)
    np.testing.assert_allclose(R @ np.swapaxes(R, 1, 2), np.broadcast_to(np.eye(3), R.shape),
                               atol=1e-12)
    np.testing.assert_allclose(matrix_to_quat(R), q, atol=1e-12)
    angle = 2 * np.arccos(np.clip(q[:, 3], -1, 1))
    np.testing.assert_allclose(rotation_angle(R), angle, atol=1e-7)
    assert rotation_angle(np.diag([1.0, -1.0, -1.0])) == pytest.approx(np.pi)
    T = _random_poses(rng, 5)
    np.testing.assert_allclose(inverse(T) @ T, np.broadcast_to(np.eye(4), T.shape), atol=1e-12)


def test_tum_and_kitti_round_trip(tmp_path):
    rng = np.random.default_rng(5)
    T = _random_poses(rng, 10)
    stamps = 1305031229.528748 + np.arange(10) / 30
    io.write_tum_trajectory(tmp_path / "t.txt", stamps, T)
    back = io.read_tum_trajectory(tmp_path / "t.txt")
    np.testing.assert_allclose(back.timestamps, stamps, atol=1e-6)
    np.testing.assert_allclose(back.poses, T, atol=1e-8)
    first = (tmp_path / "t.txt").read_text().splitlines()[0].split()
    assert first[0] == "1305031229.528748" and len(first) == 8 and len(first[1].split(".")[1]) == 9
    io.write_kitti_poses(tmp_path / "k.txt", T)
    back = io.read_kitti_poses(tmp_path / "k.txt")
    np.testing.assert_allclose(back.poses, T, atol=1e-8)
    np.testing.assert_array_equal(back.timestamps, np.arange(10.0))


def test_readers_report_problems(tmp_path):
    with pytest.raises(FileNotFoundError, match="nope.txt"):
        io.read_tum_trajectory(tmp_path / "nope.txt")
    bad = tmp_path / "bad.txt"
    bad.write_text("# header\n1.0 0 0 0 0 0 0 1\n2.0 0 0 0 0 0\n")
    with pytest.raises(ValueError, match=r"bad.txt:3"):
        io.read_tum_trajectory(bad)
    bad.write_text("1.0 0 0 0 0 0 0 1\n2.0 0 x 0 0 0 0 1\n")
    with pytest.raises(ValueError, match=r"bad.txt:2.*not a number"):
        io.read_tum_trajectory(bad)
    bad.write_text("2.0 0 0 0 0 0 0 1\n1.0 0 0 0 0 0 0 1\n")
    with pytest.raises(ValueError, match=r"bad.txt:2.*out of order"):
        io.read_tum_trajectory(bad)
    bad.write_text("1 0 0 0 0 1 0 0 0 0 1\n")
    with pytest.raises(ValueError, match="12 fields"):
        io.read_kitti_poses(bad)
