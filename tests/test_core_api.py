"""Bad input to the native ``ferroslam._core`` API: the right exception, a message naming the
problem, and a system left exactly as it was.

Valid frames are real TUM fr1/rpy frames (ORB from ``ferroslam.features``, depth sampled at
the keypoints). Image-level bad input (float / empty / NaN images) is covered by
``tests/test_features.py::test_input_validation``.
"""

from __future__ import annotations

import re

import numpy as np
import pytest

from ferroslam.datasets import TumSequence
from ferroslam.features import OrbExtractor, sample_depth

core = pytest.importorskip("ferroslam._core")
SlamSystem = core.SlamSystem

N_FRAMES = 5


@pytest.fixture(scope="module")
def camera(tum_rpy):
    return TumSequence(tum_rpy).camera


@pytest.fixture(scope="module")
def frames(tum_rpy):
    """The first frames as ``(timestamp, keypoints, descriptors, depth_m)`` tuples."""
    seq = TumSequence(tum_rpy)
    extractor = OrbExtractor()
    out = []
    for i in range(N_FRAMES):
        kp, desc = extractor.detect(seq.load_gray(i))
        out.append((float(seq.timestamps[i]), kp, desc, sample_depth(seq.load_depth(i), kp)))
    return out


def make_system(camera, **options):
    c = camera
    return SlamSystem(c.fx, c.fy, c.cx, c.cy, c.dist, c.width, c.height, **options)


def with_keypoints(frame, edit):
    """``frame`` with a copy of its keypoints changed by ``edit(kp)``."""
    t, kp, desc, depth = frame
    kp = kp.copy()
    edit(kp)
    return t, kp, desc, depth


def empty_frame(timestamp):
    return (timestamp, np.zeros((0, 5), np.float32), np.zeros((0, 32), np.uint8),
            np.zeros(0, np.float32))


def snapshot(system):
    """Everything observable about a system (timings excluded: they vary)."""
    stamps, poses = system.frame_trajectory()
    kf_ids, kf_stamps, kf_poses = system.keyframe_trajectory()
    return {
        "state": system.state, "num_keyframes": system.num_keyframes,
        "num_map_points": system.num_map_points, "num_resets": system.num_resets,
        "stamps": stamps, "poses": poses, "kf_ids": kf_ids, "kf_stamps": kf_stamps,
        "kf_poses": kf_poses, "map_points": system.map_points(),
        "map_point_colors": system.map_point_colors(),
    }


def assert_same(a, b):
    assert a.keys() == b.keys()
    for key in a:
        np.testing.assert_array_equal(a[key], b[key], err_msg=key)


def result_fields(r):
    return r.state, r.is_keyframe, r.num_tracked, None if r.T_w_c is None else r.T_w_c.tolist()


def test_points_of_frames_without_colours_are_mid_grey(camera, frames):
    """``colors`` left out: the points have none, and map_point_colors fills in the grey the
    exporters draw uncoloured points with."""
    system = make_system(camera)
    for frame in frames:
        system.track_rgbd(*frame)
    colors = system.map_point_colors()
    assert colors.dtype == np.uint8 and colors.shape == system.map_points().shape
    assert len(colors) > 500 and (colors == 128).all()


# --- arrays passed to track_rgbd --------------------------------------------------------------

def _cast(index, dtype):
    def change(frame):
        return tuple(np.asarray(a, dtype) if i == index else a for i, a in enumerate(frame))
    return change


WRONG_TYPES = {
    "keypoints float64": (_cast(1, np.float64),
                          "keypoints must be a float32 (N, 5) array, got float64 array of shape"),
    "keypoints list": (lambda f: (f[0], f[1].tolist(), f[2], f[3]),
                       "keypoints must be a float32 (N, 5) array, got list"),
    "keypoints 1-D": (lambda f: (f[0], f[1][:, 0].copy(), f[2], f[3]),
                      "keypoints must be a float32 (N, 5) array, got float32 array of shape ("),
    "descriptors int8": (_cast(2, np.int8), "descriptors must be a uint8 (N, 32) array, got int8"),
    "depth float64": (_cast(3, np.float64), "depth_m must be a float32 (N,) array, got float64"),
    "depth 2-D": (lambda f: (f[0], f[1], f[2], f[3][:, None]),
                  "depth_m must be a float32 (N,) array, got float32 array of shape ("),
}


@pytest.mark.parametrize("case", sorted(WRONG_TYPES))
def test_wrong_dtype_or_rank_is_a_type_error_naming_the_argument(camera, frames, case):
    change, message = WRONG_TYPES[case]
    with pytest.raises(TypeError, match=re.escape(message)):
        make_system(camera).track_rgbd(*change(frames[0]))


def _drop_last(index):
    def change(frame):
        return tuple(a[:-1] if i == index else a for i, a in enumerate(frame))
    return change


BAD_VALUES = {
    "keypoints (N, 4)": (lambda f: (f[0], np.ascontiguousarray(f[1][:, :4]), f[2], f[3]),
                         "keypoints must have shape (N, 5)"),
    "descriptors (N, 16)": (lambda f: (f[0], f[1], np.ascontiguousarray(f[2][:, :16]), f[3]),
                            "descriptors must have shape (N, 32)"),
    "short descriptors": (_drop_last(2), "must have the same length"),
    "short depth": (_drop_last(3), "must have the same length"),
    "short keypoints": (_drop_last(1), "must have the same length"),
    "NaN x": (lambda f: with_keypoints(f, lambda kp: kp.__setitem__((7, 0), np.nan)),
              "keypoints row 7 contains NaN or inf"),
    "inf response": (lambda f: with_keypoints(f, lambda kp: kp.__setitem__((3, 4), np.inf)),
                     "keypoints row 3 contains NaN or inf"),
    "octave 8 of 8 levels": (lambda f: with_keypoints(f, lambda kp: kp.__setitem__((5, 2), 8)),
                             "keypoint 5 has octave 8 but the pyramid has 8 levels"),
    "octave 1.5": (lambda f: with_keypoints(f, lambda kp: kp.__setitem__((2, 2), 1.5)),
                   "keypoints row 2: octave 1.5 is not a small non-negative integer"),
    "octave -1": (lambda f: with_keypoints(f, lambda kp: kp.__setitem__((2, 2), -1)),
                  "keypoints row 2: octave -1 is not a small non-negative integer"),
    "octave 300": (lambda f: with_keypoints(f, lambda kp: kp.__setitem__((2, 2), 300)),
                   "octave 300 is not a small non-negative integer"),
    "NaN timestamp": (lambda f: (float("nan"),) + f[1:], "timestamp is not finite"),
}


@pytest.mark.parametrize("case", sorted(BAD_VALUES))
def test_bad_frame_values_are_value_errors_naming_the_problem(camera, frames, case):
    change, message = BAD_VALUES[case]
    with pytest.raises(ValueError, match=re.escape(message)):
        make_system(camera).track_rgbd(*change(frames[0]))


def test_octave_limit_follows_n_levels(camera, frames):
    system = make_system(camera, n_levels=4)
    octave_4 = with_keypoints(frames[0], lambda kp: kp.__setitem__((0, 2), 4))
    with pytest.raises(ValueError, match="keypoint 0 has octave 4 but the pyramid has 4 levels"):
        system.track_rgbd(*octave_4)
    clipped = with_keypoints(frames[0], lambda kp: kp.__setitem__(
        (slice(None), 2), np.minimum(kp[:, 2], 3)))
    assert system.track_rgbd(*clipped).state == "ok"


def test_non_contiguous_arrays_are_accepted(camera, frames):
    t, kp, desc, depth = frames[0]
    strided = (t, np.asfortranarray(kp)[::-1], desc[::-1], depth[::-1])
    assert not strided[1].flags.c_contiguous and not strided[2].flags.c_contiguous
    copied = (t,) + tuple(np.ascontiguousarray(a) for a in strided[1:])
    a, b = make_system(camera), make_system(camera)
    assert result_fields(a.track_rgbd(*strided)) == result_fields(b.track_rgbd(*copied))
    assert a.state == "ok"
    assert_same(snapshot(a), snapshot(b))


@pytest.mark.parametrize("delta", [0.0, -0.01], ids=["same", "earlier"])
def test_timestamps_must_increase(camera, frames, delta):
    system = make_system(camera)
    system.track_rgbd(*frames[0])
    t0 = frames[0][0]
    with pytest.raises(ValueError, match=r"timestamp .* is not after the previous frame's"):
        system.track_rgbd(t0 + delta, *frames[1][1:])
    assert system.track_rgbd(*frames[1]).state == "ok"


def test_rejected_frames_leave_the_system_unchanged(camera, frames):
    """Interleaving every kind of rejected frame changes nothing: same results, same map."""
    clean, noisy = make_system(camera), make_system(camera)
    clean_results = [result_fields(clean.track_rgbd(*f)) for f in frames]
    noisy_results = []
    for i, frame in enumerate(frames):
        # a rejected frame with a *later* timestamp must not advance the timestamp check
        later = frames[-1][0] + 1.0
        bad = [(later,) + with_keypoints(frame, lambda kp: kp.__setitem__((0, 0), np.nan))[1:],
               (later,) + _cast(1, np.float64)(frame)[1:],
               (later,) + _drop_last(3)(frame)[1:],
               (later,) + with_keypoints(frame, lambda kp: kp.__setitem__((0, 2), 9))[1:]]
        if i > 0:
            bad.append((frames[i - 1][0],) + frame[1:])  # repeated timestamp
        for b in bad:
            with pytest.raises((TypeError, ValueError)):
                noisy.track_rgbd(*b)
        noisy_results.append(result_fields(noisy.track_rgbd(*frame)))
    assert noisy_results == clean_results
    assert clean_results[0][:2] == ("ok", True)
    assert_same(snapshot(noisy), snapshot(clean))


def test_first_real_frame_initialises_at_identity(camera, frames):
    system = make_system(camera)
    r = system.track_rgbd(*frames[0])
    assert (r.state, r.is_keyframe, system.state) == ("ok", True, "ok")
    np.testing.assert_array_equal(r.T_w_c, np.eye(4))
    assert system.num_keyframes == 1 and system.num_map_points == r.num_tracked > 500


def test_empty_frame_is_accepted_and_does_not_initialise(camera, frames):
    system = make_system(camera)
    r = system.track_rgbd(*empty_frame(frames[0][0] - 1.0))
    assert (r.state, r.is_keyframe, r.num_tracked, r.T_w_c) == ("not_initialized", False, 0, None)
    assert system.state == "not_initialized" and system.num_keyframes == 0
    assert system.track_rgbd(*frames[0]).state == "ok"


def test_empty_frame_after_initialisation_is_not_tracked(camera, frames):
    system = make_system(camera)
    system.track_rgbd(*frames[0])
    r = system.track_rgbd(*empty_frame(frames[1][0]))
    assert (r.state, r.num_tracked, r.T_w_c) == ("lost", 0, None)


def test_zero_depth_never_initialises(camera, frames):
    system = make_system(camera)
    for t, kp, desc, depth in frames:
        r = system.track_rgbd(t, kp, desc, np.zeros_like(depth))
        assert (r.state, r.is_keyframe, r.T_w_c) == ("not_initialized", False, None)
    assert system.state == "not_initialized"
    assert system.num_keyframes == 0 and system.map_points().shape == (0, 3)
    stamps, poses = system.frame_trajectory()
    assert stamps.shape == (0,) and poses.shape == (0, 4, 4)


# --- construction ---------------------------------------------------------------------------

BAD_OPTIONS = {
    "unknown name": ({"n_feature": 1000}, ValueError,
                     'unknown option "n_feature"; known: n_features'),
    "scale_factor 0.9": ({"scale_factor": 0.9}, ValueError, "scale_factor must be > 1"),
    "scale_factor NaN": ({"scale_factor": float("nan")}, ValueError, "scale_factor must be > 1"),
    "n_levels 0": ({"n_levels": 0}, ValueError, "n_levels must be in 1..=32"),
    "n_levels 33": ({"n_levels": 33}, ValueError, "n_levels must be in 1..=32"),
    "n_levels 2.5": ({"n_levels": 2.5}, TypeError, "option n_levels: expected an int, got float"),
    "seed str": ({"seed": "7"}, TypeError, "option seed: expected an int, got str"),
    "scale_factor str": ({"scale_factor": "1.2"}, TypeError,
                         "option scale_factor: expected a number, got str"),
    "loop_closure str": ({"loop_closure": "yes"}, TypeError,
                         "option loop_closure: expected a bool, got str"),
    "ini_fast 300": ({"ini_fast": 300}, ValueError, "option ini_fast: 300 is out of range"),
    "n_features -5": ({"n_features": -5}, ValueError, "option n_features: -5 is out of range"),
    "depth_threshold 0": ({"depth_threshold": 0.0}, ValueError,
                          "depth.depth_threshold must be a positive number, got 0"),
    "loop_closure_threshold 19": ({"loop_closure_threshold": 19}, ValueError,
                                  "loop_closing.loop_closure_threshold must be >= 20"),
    "track_feature_range reversed": ({"track_feature_range": (50, 10)}, ValueError,
                                     "track_feature_range must be (lower, upper) with 0 < lower"),
    "track_feature_range scalar": ({"track_feature_range": 50}, TypeError,
                                   "option track_feature_range: expected a pair of numbers"),
    "depth_range 3 values": ({"depth_range": (0.1, 4.0, 8.0)}, ValueError,
                             "option depth_range: expected 2 values, got 3"),
    "depth_range 1 value": ({"depth_range": [0.1]}, ValueError,
                            "option depth_range: expected 2 values, got 1"),
    "depth_range reversed": ({"depth_range": (8.0, 0.1)}, ValueError,
                             "depth_range must be (min, max) with 0 <= min < max"),
    "skip_max_frames 0": ({"skip_max_frames": 0}, ValueError, "skip_max_frames must be >= 1"),
    "bf 0": ({"bf": 0.0}, ValueError, "bf must be a positive number"),
}


@pytest.mark.parametrize("case", sorted(BAD_OPTIONS))
def test_bad_options(camera, case):
    options, error, message = BAD_OPTIONS[case]
    with pytest.raises(error, match=re.escape(message)):
        make_system(camera, **options)


def test_options_round_trip(camera):
    # The options a system reports are the defaults of its sensor and width, and rebuild it.
    system = make_system(camera, seed=np.int64(3), n_features=np.int64(1100))
    options = system.options
    expected = {**core.default_options("rgbd", camera.width), "seed": 3, "n_features": 1100}
    assert options == expected
    assert make_system(camera, **options).options == options


def test_fake_core_knows_the_same_options(camera):
    from fake_core import FakeSlamSystem

    with pytest.raises(ValueError, match="known: ") as err:
        make_system(camera, not_an_option=1)
    known = {k.strip() for k in str(err.value).split("known: ", 1)[1].split(",")}
    assert FakeSlamSystem.KNOWN == known


def test_good_options_and_dist_lengths(camera):
    c = camera
    # Four coefficients of a mild lens: TUM fr1's first four alone fold the image over
    # before its corners (the core refuses that, named).
    for dist in ([], [0.05, -0.1, 0.001, 0.002], c.dist, tuple(c.dist)):
        system = SlamSystem(c.fx, c.fy, c.cx, c.cy, dist, c.width, c.height, scale_factor=1.3,
                            n_levels=6, track_feature_range=[20, 200],
                            depth_range=np.array([0.2, 5.0]), skip_max_frames=10, bf=40.0,
                            depth_threshold=35.0, seed=7)
        assert system.state == "not_initialized" and system.num_resets == 0
        assert system.track_feature_range == (20, 200)
    # Without the option, each sensor's default: MATLAB's (30, 100), (30, 250) with RGB-D.
    for sensor, default in (("mono", (30, 100)), ("rgbd", (30, 250))):
        system = SlamSystem(c.fx, c.fy, c.cx, c.cy, c.dist, c.width, c.height, sensor=sensor)
        assert system.track_feature_range == default


@pytest.mark.parametrize(
    ("camera_args", "message"),
    [
        ((0.0, 516.5, 318.6, 255.3, [], 640, 480),
         "`fx` = 0: focal length must be finite and positive"),
        ((-517.3, 516.5, 318.6, 255.3, [], 640, 480), "`fx` = -517.3: focal length"),
        ((517.3, 0.0, 318.6, 255.3, [], 640, 480), "`fy` = 0: focal length"),
        ((517.3, 516.5, float("nan"), 255.3, [], 640, 480),
         "`cx` = NaN: principal point must be finite"),
        ((517.3, 516.5, 318.6, 255.3, [0.1, 0.2, 0.0], 640, 480),
         "dist must hold 0, 4 or 5 coefficients (k1 k2 p1 p2 [k3]), got 3"),
        ((517.3, 516.5, 318.6, 255.3, [float("nan")] * 5, 640, 480), "`k1` = NaN"),
        ((517.3, 516.5, 318.6, 255.3, [], 0, 480), "width = 0: image size must be positive"),
        ((517.3, 516.5, 318.6, 255.3, [], 640, -480), "height = -480: image size must be positive"),
        ((517.3, 516.5, 318.6, 255.3, [], 2**40, 480), "width = 1099511627776: image size"),
    ],
    ids=["fx 0", "fx negative", "fy 0", "cx NaN", "dist 3 values", "dist NaN", "width 0",
         "height negative", "width too large"],
)
def test_bad_camera(camera_args, message):
    with pytest.raises(ValueError, match=re.escape(message)):
        SlamSystem(*camera_args)


@pytest.mark.parametrize("sensor", ["lidar", "RGBD"])
def test_unimplemented_sensors(camera, sensor):
    with pytest.raises(NotImplementedError, match=f'sensor "{sensor}" is not implemented yet'):
        make_system(camera, sensor=sensor)


def test_mono_input_errors(camera, frames):
    t, kp, desc, depth = frames[0]
    mono = make_system(camera, sensor="mono")
    assert mono.sensor == "mono"
    with pytest.raises(ValueError, match=re.escape(
            'track_rgbd needs a system created with sensor="rgbd"; this one is "mono"')):
        mono.track_rgbd(t, kp, desc, depth)
    with pytest.raises(ValueError, match=re.escape(
            f"keypoints ({len(kp)}) and descriptors ({len(kp) - 1}) must have the same length")):
        mono.track_mono(t, kp, desc[:-1])
    with pytest.raises(TypeError, match="descriptors must be a uint8 .N, 32. array"):
        mono.track_mono(t, kp, desc.astype(np.int16))
    first = mono.track_mono(t, kp, desc)
    assert first.state == "not_initialized"
    assert first.init_reason.startswith("waiting for a reference frame")
    with pytest.raises(ValueError, match="is not after the previous frame's"):
        mono.track_mono(t, kp, desc)
    rgbd = make_system(camera)
    with pytest.raises(ValueError, match=re.escape('track_mono needs a system created with '
                                                   'sensor="mono"; this one is "rgbd"')):
        rgbd.track_mono(t, kp, desc)
