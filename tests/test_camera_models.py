"""Camera.project / Camera.unproject (the core's camera models through the bindings) against
OpenCV as the independent reference: ``cv2.fisheye.projectPoints`` for Kannala-Brandt,
``cv2.projectPoints`` with the 5 radial-tangential coefficients for the pinhole."""

from __future__ import annotations

import cv2
import numpy as np
import pytest

from ferroslam import Camera

pytest.importorskip("ferroslam._core")

# TUM RGB-D fr1 (rgb), the 5 OpenCV coefficients of the TUM calibration page.
TUM_FR1 = Camera(517.3, 516.5, 318.6, 255.3, [0.2624, -0.9531, -0.0054, 0.0026, 1.1633], 640, 480)
# TUM-VI cam0 (512x512, about 195 degrees).
TUM_VI = Camera.kannala_brandt(190.97847709874, 190.97343685097, 254.93170626452, 256.89744232891,
                               [0.00348238963613, 0.0007150348457383, -0.0020532368492876,
                                0.00020293673506033], 512, 512)
MAX_INCIDENCE_DEG = 80.0
# Coefficient ranges of real fisheye lenses (TUM-VI, T265-class: |k| up to ~0.04).
K_RANGE = np.array([0.05, 0.05, 0.03, 0.005])


def _directions(rng: np.random.Generator, n: int, max_deg: float) -> np.ndarray:
    """``n`` camera points at incidence angles uniform in ``[0, max_deg]``, any azimuth,
    ranges 0.5-10 m; the on-axis point and the largest angle included."""
    theta = np.radians(np.concatenate([[0.0, max_deg], rng.uniform(0.0, max_deg, n - 2)]))
    phi = rng.uniform(-np.pi, np.pi, n)
    rho = rng.uniform(0.5, 10.0, n)
    return rho[:, None] * np.stack(
        [np.sin(theta) * np.cos(phi), np.sin(theta) * np.sin(phi), np.cos(theta)], axis=1)


def _one_to_one(k: np.ndarray, max_deg: float) -> bool:
    """Whether ``theta_d(theta)`` grows on ``[0, max_deg]``."""
    t = np.radians(np.linspace(0.0, max_deg, 2000))
    return bool(np.all(1 + 3 * k[0] * t**2 + 5 * k[1] * t**4 + 7 * k[2] * t**6
                       + 9 * k[3] * t**8 > 0))


def _random_fisheyes(seed: int, count: int) -> list[Camera]:
    rng = np.random.default_rng(seed)
    cameras = []
    while len(cameras) < count:
        k = rng.uniform(-K_RANGE, K_RANGE)
        if not _one_to_one(k, MAX_INCIDENCE_DEG):
            continue  # such a lens would fold its image before 80 degrees
        f = rng.uniform(150.0, 500.0)
        cameras.append(Camera.kannala_brandt(f, f * rng.uniform(0.99, 1.01),
                                             rng.uniform(300, 340), rng.uniform(220, 260), k,
                                             640, 480))
    return cameras


def _unit(p: np.ndarray) -> np.ndarray:
    return p / np.linalg.norm(p, axis=1, keepdims=True)


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_kannala_brandt_equals_cv2_fisheye_and_unproject_inverts_it(seed):
    rng = np.random.default_rng(100 + seed)
    worst_px, worst_ray = 0.0, 0.0
    for camera in _random_fisheyes(seed, 10) + [TUM_VI]:
        p = _directions(rng, 500, MAX_INCIDENCE_DEG)
        uv = camera.project(p)
        expected, _ = cv2.fisheye.projectPoints(p[None], np.zeros(3), np.zeros(3), camera.K,
                                                camera.dist)
        expected = expected.reshape(-1, 2)
        px = np.abs(uv - expected).max()
        # Unprojection inverts the reference's pixels and our own.
        rays = camera.unproject(expected)
        ray = max(np.abs(rays - _unit(p)).max(), np.abs(camera.unproject(uv) - _unit(p)).max())
        worst_px, worst_ray = max(worst_px, px), max(worst_ray, ray)
        assert px <= 1e-6, f"seed {seed}, k = {camera.dist}: {px} px"
        assert ray <= 1e-9, f"seed {seed}, k = {camera.dist}: rays off by {ray}"
        np.testing.assert_allclose(np.linalg.norm(rays, axis=1), 1.0, atol=1e-12)
    print(f"seed {seed}: max |uv - cv2| {worst_px:.2e} px, max |ray - p/|p|| {worst_ray:.2e}")


def test_pinhole_equals_cv2_project_points_and_unproject_inverts_it():
    rng = np.random.default_rng(7)
    camera = TUM_FR1
    # Points whose ideal pixels cover the image (the raw image is where they are used).
    n = 2000
    ideal = np.stack([rng.uniform(0, camera.width, n), rng.uniform(0, camera.height, n)], 1)
    z = rng.uniform(0.3, 8.0, n)
    p = np.stack([(ideal[:, 0] - camera.cx) / camera.fx * z,
                  (ideal[:, 1] - camera.cy) / camera.fy * z, z], 1)
    uv = camera.project(p)
    expected, _ = cv2.projectPoints(p[None], np.zeros(3), np.zeros(3), camera.K, camera.dist)
    expected = expected.reshape(-1, 2)
    px = np.abs(uv - expected).max()
    ray = max(np.abs(camera.unproject(expected) - _unit(p)).max(),
              np.abs(camera.unproject(uv) - _unit(p)).max())
    print(f"TUM fr1: max |uv - cv2| {px:.2e} px, max |ray - p/|p|| {ray:.2e}")
    assert px <= 1e-6
    assert ray <= 1e-9
    # Without distortion the raw pixels are the ideal ones.
    plain = Camera(camera.fx, camera.fy, camera.cx, camera.cy, np.zeros(5), 640, 480)
    np.testing.assert_allclose(plain.project(p), ideal, atol=1e-9)


def test_points_a_model_cannot_project_give_nan_rows():
    p = np.array([[0.1, 0.2, 1.0], [0.0, 0.0, -1.0], [1.0, 0.0, 0.0], [np.nan, 0.0, 1.0]])
    uv = TUM_FR1.project(p)
    assert np.all(np.isfinite(uv[0])) and np.all(np.isnan(uv[1:]))
    # A 195-degree fisheye projects points beyond 90 degrees, not straight behind it.
    uv = TUM_VI.project(p)
    assert np.all(np.isfinite(uv[[0, 2]])) and np.all(np.isnan(uv[[1, 3]]))
    np.testing.assert_allclose(TUM_VI.unproject(uv[[0, 2]]), _unit(p[[0, 2]]), atol=1e-10)
    # theta_d = theta - theta^3 folds at 1/sqrt(3) rad (33 degrees).
    folding = Camera.kannala_brandt(300, 300, 320, 240, [-1.0, 0, 0, 0], 640, 480)
    tilt = np.radians([30.0, 40.0])
    uv = folding.project(np.stack([np.sin(tilt), [0, 0], np.cos(tilt)], 1))
    assert np.all(np.isfinite(uv[0])) and np.all(np.isnan(uv[1]))
    # Beyond the image circle of that angle (theta_d = 0.385) and non-finite pixels: no ray.
    rays = folding.unproject([[320 + 300 * 0.3, 240], [320 + 300 * 0.45, 240], [np.inf, 0]])
    assert np.all(np.isfinite(rays[0])) and np.all(np.isnan(rays[1:]))


def test_inputs_of_any_real_dtype_and_empty_arrays():
    p = np.array([[1, 2, 10], [0, 0, 5]])
    np.testing.assert_array_equal(TUM_VI.project(p), TUM_VI.project(p.astype(np.float32)))
    np.testing.assert_array_equal(TUM_VI.project(p.tolist()), TUM_VI.project(p.astype(float)))
    assert TUM_VI.project(np.zeros((0, 3))).shape == (0, 2)
    assert TUM_VI.unproject(np.zeros((0, 2))).shape == (0, 3)
    assert TUM_VI.project(p).dtype == np.float64


@pytest.mark.parametrize("method, value, error, message", [
    ("project", np.zeros(3), ValueError, r"points must be a float64 \(N, 3\) array, got shape "
                                         r"\(3,\)"),
    ("project", np.zeros((4, 2)), ValueError, r"points .* got shape \(4, 2\)"),
    ("project", np.zeros((2, 3), dtype=bool), TypeError, r"points .* got bool array"),
    ("project", "abc", TypeError, r"points must be a float64 \(N, 3\) array"),
    ("project", None, TypeError, r"points .* got NoneType"),
    ("unproject", np.zeros((2, 3)), ValueError, r"pixels must be a float64 \(N, 2\) array, "
                                                r"got shape \(2, 3\)"),
    ("unproject", np.zeros((2, 2), dtype=complex), TypeError, r"pixels .* complex"),
])
def test_bad_arrays_are_named(method, value, error, message):
    with pytest.raises(error, match=message):
        getattr(TUM_VI, method)(value)


def test_a_fisheye_the_core_refuses_is_a_value_error():
    # Folds over 5 degrees off the axis: the core's checks refuse it when Camera is built.
    with pytest.raises(ValueError, match=r"invalid camera: invalid parameter `k1`.*fold"):
        Camera.kannala_brandt(300, 300, 320, 240, [-100.0, 0, 0, 0], 640, 480)


@pytest.mark.parametrize("kwargs, message", [
    # The findings of issue 53: implausible cameras were accepted and "tracked".
    (dict(cx=900.0), r"`cx` = 900: principal point must lie inside the image.*640x480"),
    (dict(cy=-3.0), r"`cy` = -3: principal point must lie inside the image"),
    (dict(dist=[100.0, 0, 0, 0, 0]), r"`k1` = 100: .*factor 3"),
    (dict(dist=[1e9, 0, 0, 0, 0]), r"`k1` = 1000000000: "),
    (dict(model="kannala_brandt", dist=[1e3, -1e3, 1e3, -1e3]), r"invalid camera: .*`k\d`"),
])
def test_implausible_cameras_are_refused_at_construction(kwargs, message):
    base = dict(fx=500.0, fy=500.0, cx=320.0, cy=240.0, width=640, height=480)
    if kwargs.get("model") == "kannala_brandt":
        base["dist"] = [0.0] * 4
    with pytest.raises(ValueError, match=message):
        Camera(**{**base, **kwargs})


def test_rolling_shutter_readout_is_a_camera_attribute():
    base = dict(fx=500.0, fy=500.0, cx=320.0, cy=240.0, width=640, height=480)
    assert Camera(**base).rolling_shutter_readout_s == 0.0  # a global shutter by default
    camera = Camera(**base, rolling_shutter_readout_s=np.float32(0.025))
    assert camera.rolling_shutter_readout_s == pytest.approx(0.025)
    assert type(camera.rolling_shutter_readout_s) is float
    fisheye = Camera.kannala_brandt(300, 300, 320, 240, [0.0] * 4, 640, 480,
                                    rolling_shutter_readout_s=0.02)
    assert fisheye.rolling_shutter_readout_s == 0.02
    # The readout changes no projection: it is a time, not a lens.
    points = np.array([[0.1, -0.2, 2.0]])
    np.testing.assert_array_equal(camera.project(points), Camera(**base).project(points))


@pytest.mark.parametrize("value, error, message", [
    (-0.001, ValueError, r"rolling_shutter_readout_s must be >= 0 seconds .*-0.001"),
    (float("nan"), ValueError, r"rolling_shutter_readout_s must be finite"),
    (float("inf"), ValueError, r"rolling_shutter_readout_s must be finite"),
    ("20ms", TypeError, r"rolling_shutter_readout_s must be a real number of seconds"),
    (True, TypeError, r"rolling_shutter_readout_s must be a real number of seconds"),
])
def test_bad_readouts_are_refused_naming_the_attribute(value, error, message):
    with pytest.raises(error, match=message):
        Camera(500.0, 500.0, 320.0, 240.0, rolling_shutter_readout_s=value)


def test_the_core_refuses_a_bad_readout_too():
    from ferroslam._core import SlamSystem

    with pytest.raises(ValueError, match=r"rolling_shutter_readout_s.*readout_s"):
        SlamSystem(500.0, 500.0, 320.0, 240.0, [0.0] * 5, 640, 480,
                   rolling_shutter_readout_s=-0.01)
    SlamSystem(500.0, 500.0, 320.0, 240.0, [0.0] * 5, 640, 480, rolling_shutter_readout_s=0.02)
