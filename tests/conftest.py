"""Shared fixtures: the real-data folder (``FERROSLAM_DATA`` or ``<repo>/../shared/data``).

Tests needing data skip when it is missing, except on CI (``CI=true``), where the data is
always provisioned and a missing folder must fail loudly instead of silently skipping.
"""

from __future__ import annotations

import os
from pathlib import Path

import pytest

from ferroslam._data import data_dir

# The tests' Ray clusters live on 127.0.0.1 (ferroslam.batch's loopback switch): set before
# any test imports Ray, which reads it once.
os.environ.setdefault("RAY_ENABLE_WINDOWS_OR_OSX_CLUSTER", "0")


def require_data(*parts: str) -> Path:
    """Path inside the shared data folder; skip (locally) or fail (CI) if it is missing."""
    path = data_dir().joinpath(*parts)
    if not path.exists():
        message = f"shared test data missing: {path} (set FERROSLAM_DATA)"
        if os.environ.get("CI", "").lower() in ("1", "true", "yes"):
            pytest.fail(message)
        pytest.skip(message)
    return path


@pytest.fixture(scope="session")
def tum_rpy() -> Path:
    return require_data("tum", "rgbd_dataset_freiburg1_rpy")


@pytest.fixture(scope="session")
def tum_desk() -> Path:
    return require_data("tum", "rgbd_dataset_freiburg1_desk")


@pytest.fixture(scope="session")
def groundtruth_dir() -> Path:
    return require_data("groundtruth")


@pytest.fixture(scope="session")
def kitti_stereo() -> Path:
    return require_data("kitti", "stereo_51_frames")


@pytest.fixture(scope="session")
def euroc_micro() -> Path:
    return require_data("euroc", "V1_01_easy_micro")


@pytest.fixture(scope="session")
def kitti_mono() -> Path:
    return require_data("kitti", "odometry_06_first51")


@pytest.fixture(scope="session")
def tum_rpy_dense_run(tum_rpy):
    """One RGB-D run over the 300 frames of TUM fr1/rpy with dense fusion, shared by the
    COLMAP and dense tests (a run takes tens of seconds on CI's two cores). The dataset's
    camera, fr1's 15 ms rolling-shutter readout included: the COLMAP export moves keypoints
    to the keyframes' reference poses (``ferroslam_map::sparse_model``)."""
    from ferroslam.datasets import open_sequence
    from ferroslam.pipeline import run_sequence

    seq = open_sequence(tum_rpy)
    return seq, run_sequence(seq, {"dense": True}, sensor="rgbd", progress=False)
