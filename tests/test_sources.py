"""Videos, image folders and cameras (``ferroslam.sources``) on real frames: ``ferroslam run``
on each, the vSLAM objects fed from them, live pacing (dropped frames, latency, the current
pose) and the errors for what is missing.

The first 150 colour frames of TUM fr1/rpy are written once as a video and linked into a
folder under their TUM timestamp names. A live camera cannot be opened here: ``camera:0`` is
tested by making ``cv2.VideoCapture(0)`` open the video, the very code a camera goes
through."""

from __future__ import annotations

import json
import re
import sys
import time
from pathlib import Path

import cv2
import numpy as np
import pytest

import ferroslam
from ferroslam import cli, io, sources
from ferroslam.datasets import TumSequence
from ferroslam.vslam import MonoVSlam, TrackingStatus

sys.path.insert(0, str(Path(__file__).resolve().parent.parent / "scripts"))
from atlas_stress import FR1_SETTINGS  # noqa: E402

pytest.importorskip("ferroslam._core")

N_FRAMES = 150
# The fr1 camera in the legacy ORB-SLAM settings format (as ORB-SLAM2's TUM1.yaml).
SETTINGS = FR1_SETTINGS
# Monocular runs on these frames track 122 (video) and 126 (folder, as the TUM sequence
# itself) of the 150 (deterministic: mapping inline). The video differs because its grey
# images come from decoded colour, not from the JPEGs' luma (FFV1 is lossless, so decoding
# does not move from machine to machine). The bound is the issue's: 120 of the 150. A run
# that never initialises or loses its map for good tracks 0 to ~60.
MIN_TRACKED = 120


@pytest.fixture(scope="module")
def media(tum_rpy, tmp_path_factory):
    """``(video path, image folder, settings file)`` of the first frames."""
    root = tmp_path_factory.mktemp("sources")
    frames = TumSequence(tum_rpy, with_depth=False).frames[:N_FRAMES]
    folder = root / "rpy_images"
    folder.mkdir()
    # FFV1 is lossless and written by opencv-python-headless's FFmpeg; MJPG also works but
    # its writer here takes no quality setting (about 2 grey levels of error per pixel).
    video = root / "rpy.avi"
    writer = cv2.VideoWriter(str(video), cv2.VideoWriter_fourcc(*"FFV1"), 30.0, (640, 480))
    assert writer.isOpened()
    for frame in frames:
        (folder / frame.rgb_path.name).symlink_to(frame.rgb_path)
        writer.write(cv2.imread(str(frame.rgb_path)))
    writer.release()
    settings = root / "settings.yaml"
    settings.write_text(SETTINGS, encoding="utf-8")
    return video, folder, settings


@pytest.fixture
def camera_0_is_the_video(media, monkeypatch):
    """``cv2.VideoCapture(0)`` opens the video instead of a camera."""
    real = cv2.VideoCapture
    monkeypatch.setattr(cv2, "VideoCapture",
                        lambda target: real(str(media[0]) if target == 0 else target))


def run_cli(source, settings, out, *extra):
    """``ferroslam run SOURCE --sensor mono --camera settings``; results.json."""
    assert cli.main(["run", str(source), "--sensor", "mono", "--camera", str(settings),
                     "--out", str(out), "--silent", *extra]) == 0
    return json.loads((out / "results.json").read_text(encoding="utf-8"))


@pytest.fixture(scope="module")
def video_run(media, tmp_path_factory):
    out = tmp_path_factory.mktemp("video_run")
    return run_cli(media[0], media[2], out), out


def test_video_timestamps_come_from_the_stream(media):
    video = sources.VideoSource(media[0])
    assert len(video) == N_FRAMES and not video.live and not video.has_groundtruth
    np.testing.assert_allclose(video.timestamps, np.arange(N_FRAMES) / 30.0, atol=1e-9)
    assert video.load_gray(3).shape == (480, 640) and video.load_gray(0).dtype == np.uint8
    gray, color = video.load_gray_and_color(3)
    assert color.shape == (480, 640, 3)
    np.testing.assert_array_equal(gray, cv2.cvtColor(color, cv2.COLOR_BGR2GRAY))
    t_s, image = next(iter(video))
    assert t_s == 0.0 and image.shape == (480, 640, 3)
    with pytest.raises(ValueError, match="no calibration: .* --camera"):
        video.camera  # noqa: B018 - the property raises


def test_video_runs_from_the_command_line(video_run):
    summary, out = video_run
    assert summary["frames"] == N_FRAMES and summary["sequence"] == "rpy"
    assert summary["tracked_frames"] >= MIN_TRACKED, summary["states"]
    # No ground truth: no metrics, but every output file.
    assert summary["metrics"] == {} and "dropped_frames" not in summary
    for name in ("trajectory.txt", "keyframes.txt", "map.ply", "plot.png", "colmap"):
        assert (out / name).exists(), name
    # The video is in colour, and so are the map points.
    ply = (out / "map.ply").read_bytes()
    header, body = ply.split(b"end_header\n")
    assert b"property uchar red" in header and header.startswith(b"ply\nformat ascii")
    rgb = np.loadtxt(body.decode().splitlines(), ndmin=2)[:, 3:6]
    assert (rgb.max(axis=1) - rgb.min(axis=1)).mean() > 5


def test_image_folder_runs_from_the_command_line(media, tmp_path):
    folder = sources.ImageFolderSource(media[1])
    assert folder.timestamps[0] == pytest.approx(1305031229.528748)  # the first TUM name
    summary = run_cli(media[1], media[2], tmp_path)
    assert summary["frames"] == N_FRAMES and summary["sequence"] == "rpy_images"
    assert summary["tracked_frames"] >= MIN_TRACKED, summary["states"]


def test_a_file_source_feeds_the_vslam_object_like_the_pipeline(media, video_run):
    """``track_source`` on a video adds every frame (a file is never dropped from): a
    synchronous object gives the command line's run."""
    summary, out = video_run
    camera = ferroslam.load_calibration(media[2]).cameras[0]
    states = []
    with MonoVSlam(camera, threaded=False,
                   on_frame=lambda frame: states.append(frame.track.state)) as vslam:
        vslam.track_source(sources.VideoSource(media[0]))
        assert vslam.dropped_frames == 0 and vslam.num_processed == N_FRAMES
        stamps, poses, _ = vslam.frame_trajectory()
    assert {s: states.count(s) for s in set(states)} == summary["states"]
    written = io.read_tum_trajectory(out / "trajectory.txt")
    np.testing.assert_allclose(stamps, written.timestamps, atol=1e-6)
    np.testing.assert_allclose(poses[:, :3, 3], written.poses[:, :3, 3], atol=1e-6)


def test_camera_goes_through_the_video_code(camera_0_is_the_video, media, tmp_path):
    """``camera:0`` is live: streamed through ``MonoVSlam``, frames dropped while tracking is
    behind, every frame read either tracked or dropped."""
    source = sources.open_source("camera:0")
    assert isinstance(source, sources.CameraSource) and source.live
    summary = run_cli("camera:0", media[2], tmp_path)
    assert summary["sequence"] == "camera0" and summary["frames"] > 0
    assert summary["frames"] + summary["dropped_frames"] == N_FRAMES
    assert summary["timing_ms"]["latency_ms"]["median"] > 0
    assert (tmp_path / "trajectory.txt").exists()


class InstantLiveSource:
    """The video's frames from memory, as fast as they are asked for: a camera far faster
    than tracking. Counts the frames it gives."""

    live = True

    def __init__(self, frames):
        self.frames = frames
        self.given = 0

    def __iter__(self):
        for frame in self.frames:
            self.given += 1
            yield frame


def test_live_feed_drops_frames_and_reports_each_result(media):
    camera = ferroslam.load_calibration(media[2]).cameras[0]
    source = InstantLiveSource(list(sources.VideoSource(media[0])))
    results, poses = [], []

    def on_frame(frame):
        results.append(frame)
        poses.append(vslam.current_pose())

    with MonoVSlam(camera, on_frame=on_frame) as vslam:
        assert vslam.current_pose() == (None, TrackingStatus.NOT_INITIALIZED)
        vslam.track_source(source)
        vslam.wait()
        assert source.given == N_FRAMES
        assert vslam.dropped_frames > 0
        assert vslam.num_processed + vslam.dropped_frames == N_FRAMES
        assert [r.index for r in results] == list(range(vslam.num_processed))
    stamps = [r.timestamp_s for r in results]
    assert stamps == sorted(stamps) and all(r.latency_ms > 0 for r in results)
    # current_pose() inside the callback is the frame being reported.
    for frame, (T_w_c, status) in zip(results, poses):
        if frame.track.state == "ok":
            assert T_w_c.shape == (4, 4) and status is not TrackingStatus.LOST
            np.testing.assert_array_equal(T_w_c, frame.track.T_w_c)
        else:
            assert status is not TrackingStatus.SUCCESSFUL


def test_latest_frame_reader_hands_the_newest_frame():
    frames = [(float(i), np.zeros((2, 2), np.uint8)) for i in range(5)]
    with sources.LatestFrameReader(frames) as reader:
        time.sleep(0.2)  # the reader has long read all five
        frame, skipped = reader.take()
        assert frame[0] == 4.0 and skipped == 4
        assert reader.take() == (None, 0)


def test_folder_times_from_fps_or_names(tmp_path):
    image = np.full((8, 8), 128, np.uint8)
    for name in ("1403636579813555456.png", "1403636579763555584.png"):  # EuRoC, nanoseconds
        cv2.imwrite(str(tmp_path / name), image)
    folder = sources.ImageFolderSource(tmp_path)
    np.testing.assert_allclose(folder.timestamps, [1403636579.763555584, 1403636579.813555456])
    assert folder.paths[0].name == "1403636579763555584.png"
    np.testing.assert_allclose(sources.ImageFolderSource(tmp_path, fps=20).timestamps, [0, 0.05])
    assert [t for t, _ in sources.ImageFolderSource(tmp_path, fps=20)] == [0.0, 0.05]


@pytest.mark.parametrize("argv, message", [
    (["{video}", "--sensor", "mono"], "needs its calibration: --camera FILE"),
    (["{empty}", "--sensor", "mono", "--camera", "{settings}"], r"no images \(.png"),
    (["{named}", "--sensor", "mono", "--camera", "{settings}"],
     r"frame_a.png, ...\) are not times .* --fps"),
    (["{video}", "--sensor", "mono", "--camera", "{settings}", "--fps", "30"],
     "fps is for image folders"),
    (["{video}", "--sensor", "rgbd", "--camera", "{settings}"],
     "read with --sensor mono"),
    (["{missing}", "--sensor", "mono", "--camera", "{settings}"],
     "no video file or image folder at"),
])
def test_errors_say_what_to_give(media, tmp_path, capsys, argv, message):
    paths = {"video": media[0], "settings": media[2], "empty": tmp_path / "empty",
             "named": tmp_path / "named", "missing": tmp_path / "missing.mp4"}
    paths["empty"].mkdir()
    paths["named"].mkdir()
    cv2.imwrite(str(paths["named"] / "frame_a.png"), np.zeros((8, 8), np.uint8))
    assert cli.main(["run", *(a.format(**paths) for a in argv)]) == 1
    err = capsys.readouterr().err
    assert err.startswith("ferroslam: error:")
    assert re.search(message, err), err


def test_dataset_folders_refuse_source_options(tum_rpy, capsys):
    # --camera replaces a folder's calibration (tests/test_depth_scale.py); --fps does not apply.
    assert cli.main(["run", str(tum_rpy), "--sensor", "mono", "--fps", "30"]) == 1
    assert "--fps is for image folders" in capsys.readouterr().err
