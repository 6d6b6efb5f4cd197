"""The option schema (ferroslam.options): agrees with the core's table, refuses each bad option
of issue 53 with a message naming it, and bounds option files; hypothesis over generated
option dicts for every sensor."""

from __future__ import annotations

import json
import math
import os
import re

import numpy as np
import pytest
from hypothesis import HealthCheck, given
from hypothesis import strategies as st

from ferroslam import Camera, session
from ferroslam._core import SlamSystem, default_options
from ferroslam.calibration import ImuParams
from ferroslam.options import OPTIONS, load_option_file, validate_options
from ferroslam.session import Session
from ferroslam.vslam import MonoVSlam, RGBDVSlam, StereoVSlam
from fuzzing import fuzz

CAMERA = Camera(500.0, 500.0, 320.0, 240.0)
IMU = dict(gyroscope_noise_density=1.7e-4, gyroscope_random_walk=1.9e-5,
           accelerometer_noise_density=2.0e-3, accelerometer_random_walk=3.0e-3, rate_hz=200.0)


def _core_table() -> set[str]:
    """The names the core parses, from its own error for an unknown one."""
    with pytest.raises(ValueError, match="unknown option") as err:
        SlamSystem(500.0, 500.0, 320.0, 240.0, np.zeros(5), 640, 480, sensor="mono",
                   no_such_option=1)
    return set(re.search(r"known: (.*)$", str(err.value)).group(1).split(", "))


def test_core_declarations_are_the_core_table():
    declared = {o.name for o in OPTIONS if o.scope == "core"}
    assert declared == _core_table()
    # Every defaulted core option is declared; baseline is the one without a default (the
    # stereo system needs it given).
    for sensor in ("mono", "stereo", "rgbd"):
        assert set(default_options(sensor, 640)) == declared - {"baseline"}


def test_core_defaults_pass_the_schema():
    for sensor in ("mono", "stereo", "rgbd"):
        defaults = default_options(sensor, 640)
        applicable = {k: v for k, v in defaults.items()
                      if sensor in next(o for o in OPTIONS if o.name == k).sensors}
        assert validate_options(applicable, sensor) == {
            k: tuple(v) if isinstance(v, list) else v for k, v in applicable.items()}


@pytest.mark.parametrize("key, value, sensor, error, message", [
    ("mapping_thread", "no", "rgbd", TypeError,
     "option 'mapping_thread': expected True or False, got 'no'"),
    ("loop_closure", 1, "mono", TypeError, "option 'loop_closure': expected True or False, got 1"),
    ("gravity_magnitude", 9.81, "rgbd", ValueError,
     "option 'gravity_magnitude' is an IMU option: it applies to the -inertial sensors, and "
     "sensor 'rgbd' has no IMU"),
    ("gravity_magnitude", 1.0, "mono-inertial", ValueError,
     "option 'gravity_magnitude' = 1.0: must be in [9.7, 9.9] m/s^2"),
    ("imu_time_offset_s", 1e6, "stereo-inertial", ValueError,
     "option 'imu_time_offset_s' = 1000000.0: must be in [-1, 1] s"),
    ("threaded", True, "rgbd", ValueError,
     "option 'threaded' is taken by the vSLAM objects (MonoVSlam, StereoVSlam, RGBDVSlam) as "
     "keywords, not here"),
    ("baseline", 0.1, "rgbd", ValueError, "option 'baseline' applies to sensor stereo, not 'rgbd'"),
    ("bf", 40.0, "mono", ValueError, "option 'bf' applies to sensor rgbd, not 'mono'"),
    ("max_num_points", 2**70, "mono", ValueError,
     f"option 'max_num_points' = {2**70}: must be in [1, {2**32 - 1}] keypoints"),
    ("scale_factor", math.nan, "mono", ValueError, "option 'scale_factor' = nan: must be a "
     "finite number"),
    ("depth_range", (0.1, "far"), "rgbd", TypeError,
     "option 'depth_range': expected a number of metres, got 'far'"),
    ("track_feature_range", (100, 30), "mono", ValueError,
     "option 'track_feature_range' = (100, 30): lower must be below upper"),
    ("warp_speed", 9, "mono", ValueError, "unknown option 'warp_speed' (known: "),
])
def test_bad_option_is_refused_naming_it(key, value, sensor, error, message):
    with pytest.raises(error) as err:
        validate_options({key: value}, sensor)
    assert str(err.value).startswith(message)


def test_alias_and_name_together_are_refused():
    with pytest.raises(ValueError, match="option 'n_features' given twice "
                                         r"\(also as 'max_num_points'\)"):
        validate_options({"max_num_points": 900, "n_features": 900}, "mono")


def test_depth_range_may_end_at_infinity_and_pairs_become_tuples():
    assert validate_options({"depth_range": [0.0, math.inf], "max_num_points": 900},
                            "stereo") == {"depth_range": (0.0, math.inf), "n_features": 900}


def _mono(**options):
    return MonoVSlam(CAMERA, threaded=False, vocabulary=None, **options)


def test_vslam_localization_only_takes_bools_only():
    with _mono() as vslam:
        with pytest.raises(TypeError, match="option 'localization_only': expected True or "
                                            "False, got 'no'"):
            vslam.localization_only = "no"
        with pytest.raises(TypeError, match="option 'localization_only': expected True or "
                                            "False, got 1"):
            vslam.localization_only = 1
        vslam.localization_only = False
        assert vslam.localization_only is False


def test_vslam_keywords_go_through_the_schema():
    with pytest.raises(TypeError, match="option 'threaded': expected True or False, got 'no'"):
        MonoVSlam(CAMERA, threaded="no", vocabulary=None)
    with pytest.raises(ValueError, match=r"option 'num_levels' = 99: must be in \[1, 32\]"):
        _mono(num_levels=99)
    with pytest.raises(ValueError, match="option 'alignment_fraction' is an IMU option"):
        _mono(alignment_fraction=0.5)


@pytest.mark.parametrize("imu, error, message", [
    ({**IMU, "rate_hz": 0}, ValueError, "imu rate_hz must be a positive finite number, got 0"),
    ({k: v for k, v in IMU.items() if k != "rate_hz"}, ValueError,
     "imu: missing key(s) rate_hz"),
    ("euroc", TypeError, "imu must be ferroslam.calibration.ImuParams or a dict of its fields, "
     "got str 'euroc'"),
    ({**IMU, "gyroscope_noise_density": math.inf}, ValueError,
     "imu gyroscope_noise_density must be a positive finite number, got inf"),
    ({**IMU, "rate": 200}, ValueError, "imu: unknown key(s) rate (expected "),
    ({**IMU, "T_b_imu": np.diag([2.0, 1, 1, 1])}, ValueError,
     "imu T_b_imu is not a rigid transform"),
])
def test_bad_imu_parameters_are_refused_before_any_arithmetic(imu, error, message):
    with pytest.raises(error) as err:
        _mono(imu=imu, camera_to_imu_transform=np.eye(4))
    assert str(err.value).startswith(message)


def test_imu_options_are_checked_with_an_imu():
    with pytest.raises(ValueError, match=r"option 'imu_time_offset_s' = 1000000.0: must be in "
                                         r"\[-1, 1\] s"):
        _mono(imu=IMU, camera_to_imu_transform=np.eye(4), imu_time_offset_s=1e6)
    with _mono(imu=ImuParams(**IMU), camera_to_imu_transform=np.eye(4),
               imu_time_offset_s=0.005) as vslam:
        assert vslam.imu.rate_hz == 200.0


def test_camera_to_imu_transform_without_imu_is_refused():
    with pytest.raises(ValueError, match="camera_to_imu_transform given without imu="):
        _mono(camera_to_imu_transform=np.eye(4))
    with pytest.raises(ValueError, match="camera_to_imu_transform is not a rigid transform"):
        _mono(imu=IMU, camera_to_imu_transform=np.ones((4, 4)))


def test_stereo_vslam_refuses_a_non_camera_by_type():
    with pytest.raises(TypeError, match="intrinsics must be a ferroslam.Camera, got str"):
        StereoVSlam("cam", 0.11)


def test_add_frame_none_is_a_type_error():
    with _mono() as vslam:
        with pytest.raises(TypeError, match=r"image must be a numpy array \(H, W\) or "
                                            r"\(H, W, 3\), got NoneType"):
            vslam.add_frame(None)
    with RGBDVSlam(CAMERA, 5000, threaded=False, vocabulary=None) as vslam:
        with pytest.raises(TypeError, match="color image must be a numpy array"):
            vslam.add_frame(None, np.zeros((480, 640)))


def test_session_refuses_depth_of_another_size():
    # The pipeline and the CLI track through Session.track: the core's door checks it, not
    # only RGBDVSlam.add_frame.
    s = Session(CAMERA, "rgbd", vocabulary=None)
    with pytest.raises(ValueError, match=r"the depth image is 320x240 but the camera is "
                                         r"640x480 \(width x height\)"):
        s.track(1.0, np.zeros((480, 640), np.uint8), depth_m=np.zeros((240, 320), np.float32))
    assert session.IMU_KEYS == ("num_poses_threshold", "alignment_fraction",
                                "gravity_magnitude", "imu_time_offset_s")


# -- option files ---------------------------------------------------------------------------

def test_option_file_json_and_yaml(tmp_path):
    (tmp_path / "a.json").write_text('{"n_features": 900, "track_feature_range": [20, 90]}')
    assert load_option_file(tmp_path / "a.json") == {"n_features": 900,
                                                     "track_feature_range": [20, 90]}
    (tmp_path / "a.yaml").write_text("n_features: 900\nmapping_thread: false\n")
    assert load_option_file(tmp_path / "a.yaml") == {"n_features": 900, "mapping_thread": False}


def test_deeply_nested_files_are_refused_not_recursion_errors(tmp_path):
    deep = tmp_path / "deep.json"
    deep.write_text('{"a": ' + "[" * 200_000 + "]" * 200_000 + "}")
    with pytest.raises(ValueError, match=f"{deep}: nested deeper than 16 levels"):
        load_option_file(deep)
    block = tmp_path / "deep.yaml"  # block style: depth known only after parsing
    block.write_text("".join(f"{'  ' * i}k{i}:\n" for i in range(40)) + "  " * 40 + "v\n")
    with pytest.raises(ValueError, match=f"{block}: nested deeper than 16 levels"):
        load_option_file(block)
    quoted = tmp_path / "quoted.json"  # brackets inside strings are not nesting
    quoted.write_text(json.dumps({"vocabulary": "[" * 100}))
    assert load_option_file(quoted) == {"vocabulary": "[" * 100}


def test_option_file_errors_name_the_file(tmp_path):
    with pytest.raises(IsADirectoryError, match=f"{tmp_path}: is a directory"):
        load_option_file(tmp_path)
    with pytest.raises(FileNotFoundError, match="options file not found"):
        load_option_file(tmp_path / "missing.json")
    latin = tmp_path / "latin.json"
    latin.write_bytes(b'{"vocabulary": "caf\xe9"}')
    with pytest.raises(ValueError, match=f"{latin}: not UTF-8 text"):
        load_option_file(latin)
    big = tmp_path / "big.json"
    big.write_text("{}" + " " * 2000)
    with pytest.raises(ValueError, match=f"{big}: 2002 bytes, more than the 1000 a options "
                                         "file may have"):
        load_option_file(big, max_bytes=1000)
    fifo = tmp_path / "fifo"
    os.mkfifo(fifo)
    with pytest.raises(ValueError, match=f"{fifo}: is a FIFO, expected a regular options file"):
        load_option_file(fifo)  # refused before open(): nothing blocks
    bad = tmp_path / "bad.json"
    bad.write_text("{")
    with pytest.raises(ValueError, match=f"{bad}: invalid JSON"):
        load_option_file(bad)


# -- generated option dicts -----------------------------------------------------------------

_NAMES = [o.name for o in OPTIONS] + [a for o in OPTIONS for a in o.aliases]
_VALUES = st.one_of(
    st.booleans(), st.integers(-2**70, 2**70), st.floats(allow_nan=True, allow_infinity=True),
    st.text(max_size=5), st.none(),
    st.lists(st.one_of(st.integers(-10, 500), st.floats(-1, 1e3), st.text(max_size=2)),
             max_size=3),
)
_KEYS = st.one_of(st.sampled_from(_NAMES), st.text(min_size=1, max_size=8))
_SENSORS = st.sampled_from(["mono", "stereo", "rgbd", "mono-inertial", "stereo-inertial",
                            "rgbd-inertial"])


@given(st.dictionaries(_KEYS, _VALUES, max_size=4), _SENSORS)
@fuzz(400, deadline=200, suppress_health_check=[HealthCheck.too_slow])
def test_generated_options_succeed_or_name_the_key(options, sensor):
    try:
        out = validate_options(options, sensor)
    except (TypeError, ValueError) as err:
        assert any(repr(k) in str(err) for k in options), (options, str(err))
        return
    by_name = {o.name: o for o in OPTIONS}
    for name, value in out.items():
        assert by_name[name].scope in ("core", "imu", "pipeline")
        if by_name[name].kind == "flag":
            assert isinstance(value, bool)
        if by_name[name].kind == "float":
            assert math.isfinite(value)


@pytest.mark.parametrize("config, error, message", [
    ({"mapping_thread": "no"}, TypeError,
     "option 'mapping_thread': expected True or False, got 'no'"),
    ({"gravity_magnitude": 9.81}, ValueError, "option 'gravity_magnitude' is an IMU option"),
    ({"threaded": True}, ValueError, "option 'threaded' is taken by the vSLAM objects"),
    ({"localization_only": True}, ValueError,
     "option 'localization_only' is taken by the vSLAM objects as an attribute"),
])
def test_run_sequence_checks_its_config_before_reading_frames(config, error, message):
    class Unread:  # run_sequence must refuse the config before touching the sequence
        name = "unread"

    from ferroslam.pipeline import run_sequence

    with pytest.raises(error) as err:
        run_sequence(Unread(), config, sensor="rgbd", progress=False)
    assert str(err.value).startswith(message)
