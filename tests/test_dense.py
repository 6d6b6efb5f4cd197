"""TSDF fusion of RGB-D keyframes (ferroslam.dense): the mesh of a TUM fr1/rpy run is a
surface the frames left out of the fusion see where it is."""

from __future__ import annotations

import numpy as np
import pytest

from ferroslam.dense import fuse_tsdf, require_open3d, write_dense_outputs

# Frames not fused whose depth is compared with the mesh.
HELD_OUT_FRAMES = 30
# Every 8th pixel of each held-out depth image (4,800 per 640x480 frame): enough for a
# median, a 64th of the work.
PIXEL_STRIDE = 8


def _open3d():
    try:
        return require_open3d()
    except ImportError as err:
        import os

        if os.environ.get("CI", "").lower() in ("1", "true", "yes"):
            pytest.fail(str(err))
        pytest.skip(str(err))


def _pose_at(stamps: np.ndarray, poses: np.ndarray, t: float, tolerance_s: float = 0.02):
    """The pose of the nearest timestamp (TUM's association tolerance)."""
    i = int(np.argmin(np.abs(stamps - t)))
    assert abs(stamps[i] - t) <= tolerance_s
    return poses[i]


def _median_distance_m(o3d, dense, seq, frames, T_w_c) -> float:
    """Median distance to the mesh of the held-out frames' depth, back-projected at
    ``T_w_c`` (one pose per frame), over pixels with depth inside the fused range."""
    mesh = o3d.t.geometry.TriangleMesh()
    mesh.vertex.positions = o3d.core.Tensor(dense.vertices.astype(np.float32))
    mesh.triangle.indices = o3d.core.Tensor(dense.triangles.astype(np.int32))
    scene = o3d.t.geometry.RaycastingScene()
    scene.add_triangles(mesh)
    camera = seq.camera
    v, u = np.mgrid[0:camera.height:PIXEL_STRIDE, 0:camera.width:PIXEL_STRIDE]
    rays = camera.unproject(np.column_stack([u.ravel(), v.ravel()]).astype(np.float64))
    distances = []
    for i, T in zip(frames, T_w_c):
        depth = seq.load_depth(i)[v.ravel(), u.ravel()]
        ok = (depth > 0) & (depth < 4.0) & np.isfinite(rays).all(axis=1)
        p_c = rays[ok] / rays[ok, 2:3] * depth[ok, None]  # depth is z, not range
        p_w = p_c @ T[:3, :3].T + T[:3, 3]
        distances.append(scene.compute_distance(o3d.core.Tensor(p_w.astype(np.float32)))
                         .numpy())
    return float(np.median(np.concatenate(distances)))


def test_rgbd_mesh_is_where_unfused_frames_see_the_surface(tum_rpy_dense_run, tmp_path):
    o3d = _open3d()
    seq, result = tum_rpy_dense_run
    dense = result.dense
    print(f"fusion of {dense.frames} keyframes: {dense.fusion_s:.2f} s, "
          f"{len(dense.vertices)} vertices, {len(dense.triangles)} triangles, "
          f"{len(dense.points)} dense points")
    assert dense.frames == len(result.keyframes) and len(dense.vertices) > 10_000
    assert len(dense.triangles) > len(dense.vertices)  # a surface, not scattered points

    keyframe_stamps = set(result.keyframes.timestamps.tolist())
    tracked = [i for i, t in enumerate(seq.timestamps)
               if t in set(result.trajectory.timestamps.tolist()) and t not in keyframe_stamps]
    frames = [tracked[k] for k in np.linspace(0, len(tracked) - 1, HELD_OUT_FRAMES).astype(int)]
    est_stamps, est_poses = result.trajectory.timestamps, result.trajectory.poses
    estimated_m = _median_distance_m(
        o3d, dense, seq, frames,
        [_pose_at(est_stamps, est_poses, seq.timestamps[i]) for i in frames])

    # The reference: the same keyframes fused at their ground-truth poses.
    gt_stamps, gt_poses = seq.groundtruth()
    reference = fuse_tsdf(
        seq.camera, [_pose_at(gt_stamps, gt_poses, t) for t in result.keyframes.timestamps],
        [result.keyframe_images.image(t) for t in result.keyframes.timestamps],
        [result.keyframe_images.depth_m(t) for t in result.keyframes.timestamps])
    reference_m = _median_distance_m(
        o3d, reference, seq, frames,
        [_pose_at(gt_stamps, gt_poses, seq.timestamps[i]) for i in frames])
    print(f"median distance of {HELD_OUT_FRAMES} unfused frames' depth to the mesh: "
          f"{estimated_m * 100:.2f} cm at the estimated poses, {reference_m * 100:.2f} cm "
          "with the ground-truth poses")
    assert estimated_m < 0.02

    write_dense_outputs(tmp_path, dense)
    mesh = o3d.io.read_triangle_mesh(str(tmp_path / "mesh.ply"))
    assert len(mesh.vertices) == len(dense.vertices) and mesh.has_vertex_colors()
    np.testing.assert_allclose(np.asarray(mesh.vertices), dense.vertices, atol=1e-5)
    assert len(o3d.io.read_point_cloud(str(tmp_path / "dense.ply")).points) == len(dense.points)


def test_rgbd_object_fuses_its_keyframes(tum_rpy):
    _open3d()
    from ferroslam.datasets import open_sequence
    from ferroslam.vslam import RGBDVSlam

    seq = open_sequence(tum_rpy)
    with RGBDVSlam(seq.camera, depth_scale_factor=1.0, threaded=False) as vslam:
        for i in range(40):
            gray, color = seq.load_gray_and_color(i)
            vslam.add_frame(color, seq.load_depth(i), seq.timestamps[i])
        ids, _ = vslam.poses()
        dense = vslam.dense_mesh(voxel_m=0.02, truncation_m=0.08)
        with pytest.raises(ValueError, match="dense_truncation_m"):
            vslam.dense_mesh(voxel_m=0.05, truncation_m=0.04)
    assert dense.frames == len(ids) >= 2
    assert len(dense.vertices) > 1000
