"""Keypoint masks (issue 57, item 4): a camera's static mask (an array, a calibration file's
``mask:`` image, ``--mask``), a frame's own (``add_frame(..., mask=)``) and the fisheye image
circle (``Camera.with_image_circle_mask``), honoured by extraction in every mode."""

from __future__ import annotations

import dataclasses

import cv2
import numpy as np
import pytest
from conftest import require_data
from test_fisheye_tracking import FISHEYE, FisheyeTum

from ferroslam import Camera, metrics
from ferroslam.calibration import load_calibration
from ferroslam.cli import _open_input, build_parser
from ferroslam.datasets.tum import TumSequence
from ferroslam.features import OrbExtractor
from ferroslam.pipeline import run_sequence
from ferroslam.trajectory import Trajectory
from ferroslam.vslam import MonoVSlam, RGBDVSlam, StereoVSlam

W, H = 640, 480


def _lower_third_closed() -> np.ndarray:
    mask = np.full((H, W), 255, np.uint8)
    mask[2 * H // 3:] = 0
    return mask


def _on_closed_pixels(keypoints: np.ndarray, mask: np.ndarray) -> int:
    """Keypoints whose rounded position (as ``sample_depth`` rounds) is a 0 mask pixel."""
    u, v = np.rint(keypoints[:, 0]).astype(int), np.rint(keypoints[:, 1]).astype(int)
    return int(np.count_nonzero(mask[v, u] == 0))


@pytest.fixture(scope="module")
def rpy_frame(tum_rpy) -> np.ndarray:
    return TumSequence(tum_rpy).load_gray(0)


# --- the extractor ----------------------------------------------------------------------------


def test_a_mask_moves_the_budget_and_an_open_mask_changes_nothing(rpy_frame):
    extractor = OrbExtractor()
    keypoints, descriptors = extractor.detect(rpy_frame)
    mask = _lower_third_closed()
    masked, masked_descriptors = extractor.detect(rpy_frame, mask)
    assert _on_closed_pixels(masked, mask) == 0
    assert len(masked) == len(masked_descriptors)
    above = np.count_nonzero(np.rint(keypoints[:, 1]) < 2 * H // 3)
    # The spread runs after the mask: the open two thirds get more than the share they had
    # (measured on frame 0: 1000 keypoints masked; 751 of 1000 above the line unmasked).
    assert len(masked) > above + 100, (len(masked), above)
    for open_mask in (np.ones((H, W), np.uint8), np.ones((H, W), bool)):
        again, again_descriptors = extractor.detect(rpy_frame, open_mask)
        np.testing.assert_array_equal(again, keypoints)
        np.testing.assert_array_equal(again_descriptors, descriptors)


def test_bad_masks_are_refused_naming_the_problem(rpy_frame):
    extractor = OrbExtractor()
    cases = [
        (np.ones((H, W - 1), np.uint8),
         "mask is 639x480 (width x height) but the image is 640x480"),
        (np.ones((H, W), np.float32), "mask must be uint8 or bool (0 = no keypoint there), "
                                      "got float32"),
        (np.ones((H, W, 1), np.uint8), "mask must be 2-D (H, W), got shape (480, 640, 1)"),
        ([[1, 0]], "mask must be a numpy array (H, W) uint8 or bool, got list"),
    ]
    for mask, message in cases:
        with pytest.raises(ValueError) as err:
            extractor.detect(rpy_frame, mask)
        assert str(err.value) == message


def test_the_core_refuses_bad_masks_itself(rpy_frame):
    from ferroslam import _core

    core = _core.OrbExtractor()
    with pytest.raises(ValueError) as err:
        core.extract(rpy_frame, np.ones((10, 20), np.uint8))
    assert str(err.value) == ("mask: the mask is 20x10 (width x height) but the image is "
                              "640x480: give a mask of the image's size (0 = no keypoint there)")
    with pytest.raises(ValueError) as err:
        core.extract_stereo(rpy_frame, rpy_frame, None, np.ones((H, W), np.int64))
    assert str(err.value) == "right_mask dtype must be uint8 or bool, got int64"
    left, right = core.extract_stereo(rpy_frame, rpy_frame, None, _lower_third_closed())
    assert _on_closed_pixels(right[0], _lower_third_closed()) == 0
    assert _on_closed_pixels(left[0], _lower_third_closed()) > 0


# --- the camera's static mask and the image circle --------------------------------------------


def test_the_image_circle_mask():
    camera = FISHEYE.with_image_circle_mask(200.0, margin_px=8.0)
    mask = camera.mask
    assert mask.shape == (H, W) and mask.dtype == np.uint8 and not mask.flags.writeable
    v, u = np.mgrid[0:H, 0:W]
    r = np.hypot(u - FISHEYE.cx, v - FISHEYE.cy)
    np.testing.assert_array_equal(mask > 0, r <= 192.0)
    # None: the largest circle around the principal point inside the image (cy + 0.5 = 240).
    largest = FISHEYE.with_image_circle_mask(margin_px=0.0).mask
    np.testing.assert_array_equal(largest > 0, r <= 240.0)
    # From the lens: a ray 30 degrees off the axis lands at 480 * theta_d(pi / 6) px.
    theta = np.pi / 6
    k1, k2, k3, k4 = FISHEYE.dist
    theta_d = theta * (1 + k1 * theta**2 + k2 * theta**4 + k3 * theta**6 + k4 * theta**8)
    lens = FISHEYE.with_image_circle_mask(margin_px=0.0, field_of_view_deg=60.0).mask
    np.testing.assert_array_equal(lens > 0, r <= 480.0 * theta_d + 1e-9)
    # Combined with the mask the camera has: open only where both are.
    both = FISHEYE.with_mask(_lower_third_closed()).with_image_circle_mask(200.0, 8.0).mask
    np.testing.assert_array_equal(both > 0, (r <= 192.0) & (v < 2 * H // 3))
    with pytest.raises(ValueError, match="radius_px or field_of_view_deg, not both"):
        FISHEYE.with_image_circle_mask(100.0, field_of_view_deg=60.0)
    with pytest.raises(ValueError, match="margin must be finite and >= 0, got -1 px"):
        FISHEYE.with_image_circle_mask(100.0, margin_px=-1.0)


def test_a_camera_mask_is_checked_against_the_camera():
    camera = Camera(500.0, 500.0, 319.5, 239.5)
    with pytest.raises(ValueError) as err:
        camera.with_mask(np.ones((240, 320), np.uint8))
    assert str(err.value) == ("the camera's mask is 320x240 (width x height) but the image "
                              "is 640x480")
    with pytest.raises(ValueError) as err:
        camera.with_mask(np.ones((H, W), np.int32))
    assert str(err.value) == ("the camera's mask must be uint8 or bool (0 = no keypoint "
                              "there), got int32")
    assert camera.with_mask(np.ones((H, W), bool)).mask.dtype == np.uint8
    assert "mask" not in repr(camera.with_mask(np.ones((H, W), np.uint8)))


def test_a_flat_calibration_names_its_mask_image_and_run_takes_mask(tmp_path, tum_rpy):
    cv2.imwrite(str(tmp_path / "mask.png"), _lower_third_closed())
    (tmp_path / "camera.yaml").write_text(
        "fx: 517.3\nfy: 516.5\ncx: 318.6\ncy: 255.3\nwidth: 640\nheight: 480\n"
        "mask: mask.png\n")
    camera = load_calibration(tmp_path / "camera.yaml").cameras[0]
    np.testing.assert_array_equal(camera.mask, _lower_third_closed())
    (tmp_path / "bad.yaml").write_text("fx: 517.3\nfy: 516.5\ncx: 318.6\ncy: 255.3\n"
                                       "mask: missing.png\n")
    with pytest.raises(FileNotFoundError, match="missing.png does not exist"):
        load_calibration(tmp_path / "bad.yaml")
    args = build_parser().parse_args(["run", str(tum_rpy), "--sensor", "rgbd", "--mask",
                                     str(tmp_path / "mask.png")])
    seq, notes = _open_input(args)
    np.testing.assert_array_equal(seq.camera.mask, _lower_third_closed())
    assert notes[-1] == f"static mask from {tmp_path / 'mask.png'}"


# --- per-frame masks through add_frame --------------------------------------------------------


def test_add_frame_takes_a_per_frame_mask(tum_rpy):
    seq = TumSequence(tum_rpy)
    seen: list[np.ndarray] = []
    mask = np.zeros((H, W), bool)
    mask[:, : W // 2] = True  # only the left half
    for cls in (MonoVSlam, RGBDVSlam):
        vslam = cls(seq.camera.with_mask(_lower_third_closed()), vocabulary=None, threaded=False)
        _spy(seen, vslam._session)
        for i in range(3):
            image = seq.load_gray(i)
            frame_mask = mask if i != 1 else None
            if cls is MonoVSlam:
                vslam.add_frame(image, float(seq.timestamps[i]), mask=frame_mask)
            else:
                vslam.add_frame(image, seq.load_depth(i), float(seq.timestamps[i]),
                                mask=frame_mask)
        vslam.wait()
        both = np.where(mask, _lower_third_closed(), 0).astype(np.uint8)
        assert _on_closed_pixels(seen[-3], both) == 0 and len(seen[-3]) > 300
        assert _on_closed_pixels(seen[-2], _lower_third_closed()) == 0
        assert np.count_nonzero(seen[-2][:, 0] > W / 2 + 1) > 100  # the static mask alone
        assert _on_closed_pixels(seen[-1], both) == 0
        with pytest.raises(ValueError) as err:
            if cls is MonoVSlam:
                vslam.add_frame(seq.load_gray(3), mask=np.ones((H, W, 3), np.uint8))
            else:
                vslam.add_frame(seq.load_gray(3), seq.load_depth(3), mask=np.ones((H, 2), np.uint8))
        expected = ("masks must be (H, W), got shape (480, 640, 3)" if cls is MonoVSlam
                    else "invalid input: mask is 2x480 but the camera is 640x480 (width x "
                         "height)")
        assert str(err.value) == expected
        vslam.close()


def _spy(seen: list, session) -> None:
    """Records each frame's keypoints (every camera's) as ``session`` tracks it."""
    track = session.track

    def call(*args, **kwargs):
        result = track(*args, **kwargs)
        cameras = result.camera_keypoints
        seen.append(cameras[0] if len(cameras) == 1 else tuple(cameras))
        return result
    session.track = call


def test_stereo_add_frame_masks_each_image(tum_rpy):
    seq = TumSequence(tum_rpy)
    camera = dataclasses.replace(seq.camera, dist=np.zeros(5))
    vslam = StereoVSlam(camera, 0.1, vocabulary=None, threaded=False)
    seen: list = []
    _spy(seen, vslam._session)
    image = seq.load_gray(0)
    vslam.add_frame(image, image, 0.0, mask=(_lower_third_closed(), None))
    vslam.add_frame(image, image, 0.1, mask=_lower_third_closed())
    vslam.wait()
    (left0, right0), (left1, right1) = seen
    assert _on_closed_pixels(left0, _lower_third_closed()) == 0
    assert _on_closed_pixels(right0, _lower_third_closed()) > 0
    assert _on_closed_pixels(left1, _lower_third_closed()) == 0
    assert _on_closed_pixels(right1, _lower_third_closed()) == 0
    with pytest.raises(ValueError) as err:
        vslam.add_frame(image, image, 0.2, mask=(None, np.ones((H, W), np.float64)))
    assert str(err.value) == "masks[1] dtype must be uint8 or bool, got float64"
    with pytest.raises(ValueError) as err:
        vslam.add_frame(image, image, 0.2, mask=(None, None, None))
    assert str(err.value) == "mask must be one (H, W) array or a (left, right) pair, got 3 masks"
    vslam.close()


# --- real runs --------------------------------------------------------------------------------


def test_rgbd_with_the_lower_third_masked(tum_rpy):
    """fr1/rpy RGB-D, 300 frames, no keypoint in the lower third. Measured: 300/300
    tracked, ATE 1.41 cm (unmasked: 2.15 cm, tests/test_e2e_rgbd.py); the bound is the
    issue's 3 cm."""
    mask = _lower_third_closed()
    seq = TumSequence(tum_rpy, camera=TumSequence(tum_rpy).camera.with_mask(mask))
    closed = []

    def on_frame(result, *, keypoints, **_):
        closed.append(_on_closed_pixels(keypoints, mask))

    result = run_sequence(seq, progress=False, on_frame=on_frame)
    ate = metrics.ate(Trajectory(*seq.groundtruth()), result.trajectory, align="se3")
    print(f"fr1/rpy RGB-D, lower third masked: {result.tracked_frames}/{result.frames} "
          f"tracked, ATE {ate.rmse * 100:.2f} cm")
    assert len(closed) == result.frames == 300
    assert sum(closed) == 0
    assert result.tracked_frames == 300
    assert ate.rmse <= 0.030


class CircleMaskedFisheyeTum(FisheyeTum):
    """``FisheyeTum`` (black border left in) whose camera masks outside the image circle:
    the largest circle around the principal point inside the re-imaged Kinect view."""

    def __init__(self, path, margin_px: float) -> None:
        super().__init__(path)
        v, u = np.nonzero(self.map_x < -999.0)
        radius_px = float(np.min(np.hypot(u - FISHEYE.cx, v - FISHEYE.cy)))
        self.camera = FISHEYE.with_image_circle_mask(radius_px, margin_px)


def test_fisheye_mono_with_the_border_in_and_the_circle_masked():
    """The issue's case: the re-imaged fisheye frames with their black border, the circle
    mask on (margin 8 px, the default), monocular. Every frame's keypoints stay inside the
    circle.

    The issue's target, >= 250/300 frames in one map, is reached with the frames of the
    tracking gaps posed afterwards (``gap_frames``): seed 0 (the default) 270/300 poses in
    one map, Sim(3) ATE 2.88 cm, of which 238 tracked live. Before the gaps were filled
    (inline, deterministic per seed; ``{"seed": s}``): seed 0 238/300 in one map, 2.74 cm
    (231/300 in 2 maps before the atlas kept a lost map and resumed it); before the
    atlas, seeds 1-3: 254/300 in 1, 200/300 in 2, 219/300 in 3. Without the mask: seed 0
    212/300 in 3 segments (the issue's figure), seed 1 299/300 in 1. Margins 0-24 px at seed
    0 gave 208-287 frames with no trend. The count is decided by whether the map survives
    the fast rotations around frames 90-120, which the RANSAC seed moves more than the mask
    does. Bounds: live, the unmasked run's 212/300 on the same seed; the ATE as the pinhole
    run's with its gaps filled (tests/test_gap_filling.py: 3.02 cm, bound 3.5 cm)."""
    seq = CircleMaskedFisheyeTum(require_data("tum", "rgbd_dataset_freiburg1_rpy"), 8.0)
    closed = []

    def on_frame(result, *, keypoints, **_):
        closed.append(_on_closed_pixels(keypoints, seq.camera.mask))

    result = run_sequence(seq, sensor="mono", progress=False, on_frame=on_frame)
    segments = result.num_maps
    print(f"fisheye mono, circle mask: {result.tracked_frames}/{result.frames} tracked, "
          f"{segments} map(s), {result.largest_map.frames} poses in the largest, "
          f"ATE {result.ate_frames.rmse * 100:.2f} cm")
    assert len(closed) == 300 and sum(closed) == 0
    assert result.tracked_frames >= 212
    assert segments == 1 and result.largest_map.frames >= 250
    assert result.ate_frames.pairs == result.largest_map.frames
    assert result.ate_frames.rmse <= 0.035
