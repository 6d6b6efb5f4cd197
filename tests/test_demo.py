"""The bundled sample and ``ferroslam demo`` (real core, real frames: no shared data needed).

Measured on this build (2-core machine): RGB-D 90/90 frames tracked, ATE 2.27 cm (SE(3)),
14.9 ms per frame median; monocular initialised at frame 2, 88/90 tracked, ATE 2.83 cm
(Sim(3)). Bounds sit ~30 % above.
"""

from __future__ import annotations

import json
import tarfile
from pathlib import Path

import numpy as np
import pytest

from ferroslam import cli, io
from ferroslam.demo import SAMPLE_ARCHIVE, SAMPLE_NAME, extract_sample, sample_sequence
from ferroslam.datasets import TUM_CAMERAS

RGBD_ATE_BOUND_M = 0.03
MONO_ATE_BOUND_M = 0.04


def test_sample_archive_is_small_and_licensed():
    assert SAMPLE_ARCHIVE.stat().st_size <= 8_000_000
    with tarfile.open(SAMPLE_ARCHIVE) as tar:
        names = tar.getnames()
        readme = tar.extractfile(f"{SAMPLE_NAME}/README.md").read().decode()
    assert sum(n.startswith(f"{SAMPLE_NAME}/rgb/") and n.endswith(".jpg") for n in names) == 90
    assert sum(n.startswith(f"{SAMPLE_NAME}/depth/") and n.endswith(".png") for n in names) == 90
    assert "CC BY 4.0" in readme and "Sturm" in readme and "IROS" in readme
    assert "CC BY 4.0" in (SAMPLE_ARCHIVE.parent / "README.md").read_text()


def test_sample_sequence_is_a_tum_sequence():
    with sample_sequence() as seq:
        folder = seq.path
        assert len(seq) == 90 and seq.camera is TUM_CAMERAS[1]
        assert np.all(np.diff(seq.timestamps) > 0.02)
        depth = seq.load_depth(0)
        assert depth.shape == (480, 640) and 0.3 < np.median(depth[depth > 0]) < 5.0
        assert seq.load_gray(89).shape == (480, 640)
        gt_t, _ = seq.groundtruth()
        assert gt_t[0] <= seq.timestamps[0] and gt_t[-1] >= seq.timestamps[-1]
    assert not folder.exists()  # the temporary extraction is removed


def test_extract_sample(tmp_path):
    assert (extract_sample(tmp_path) / "rgb.txt").is_file()


def test_demo_rgbd(tmp_path, capsys):
    out = tmp_path / "demo"
    assert cli.main(["demo", "--out", str(out)]) == 0
    printed = capsys.readouterr().out
    assert "tracked frames  90/90" in printed and "ATE frames" in printed
    assert "time per frame  median" in printed
    results = json.loads((out / "results.json").read_text())
    assert results["tracked_frames"] == 90
    assert results["metrics"]["ate_frames"]["rmse"] < RGBD_ATE_BOUND_M
    # The scale error is the Sim(3) alignment's (+21.9 % on these 90 frames, 2026-12-01: 3 s
    # of mostly rotation, 0.31 m of path, leave the scale loosely determined), not the path
    # length ratio, which per-frame jitter inflates: 1.94 as a global shutter (it was
    # reported as +94 %), 1.29 with fr1's rolling shutter modelled (2026-12-02).
    assert abs(results["metrics"]["scale_error"]) < 0.5
    assert results["metrics"]["path_length"]["ratio"] < 1.5
    assert f"scale error     {100 * results['metrics']['scale_error']:+.2f} %" in printed
    assert "(Sim(3) alignment's scale)" in printed
    assert len(io.read_tum_trajectory(out / "trajectory.txt")) == 90
    ply = (out / "map.ply").read_bytes()
    assert ply.startswith(b"ply\n") and f"element vertex {results['map_points']}".encode() in ply
    assert results["map_points"] > 500
    assert (out / "plot.png").stat().st_size > 20_000


def test_demo_mono(tmp_path, capsys):
    out = tmp_path / "mono"
    assert cli.main(["demo", "--sensor", "mono", "--out", str(out), "--silent"]) == 0
    assert capsys.readouterr().out == ""
    results = json.loads((out / "results.json").read_text())
    assert results["sensor"] == "mono" and results["config"] == {"n_features": 1500}
    assert results["first_initialised_frame"] <= 5 and results["tracked_frames"] >= 80
    assert results["metrics"]["ate_frames"]["rmse"] < MONO_ATE_BOUND_M


def test_demo_arguments():
    args = cli.build_parser().parse_args(["demo"])
    assert (args.sensor, args.max_frames, args.out) == ("rgbd", None, None)
    args = cli.build_parser().parse_args(["demo", "--sensor", "mono", "--max-frames", "30",
                                          "--out", "o"])
    assert (args.sensor, args.max_frames, args.out) == ("mono", 30, Path("o"))
    with pytest.raises(SystemExit):
        cli.build_parser().parse_args(["demo", "--sensor", "stereo"])
