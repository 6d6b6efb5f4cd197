"""Command-line parser, ``eval`` on real files, and ``run``/pipeline with a fake core."""

from __future__ import annotations

import json
import subprocess
import sys
from functools import partial
from pathlib import Path

import numpy as np
import pytest

import ferroslam
from ferroslam import cli, io, pipeline, session
from ferroslam.datasets import TumSequence

from fake_core import FakeSlamSystem

REPO = Path(__file__).resolve().parents[1]


def test_run_arguments():
    args = cli.build_parser().parse_args(
        ["run", "seq", "--sensor", "rgbd", "--max-frames", "5", "--out", "o", "--seed", "3",
         "--config", "c.json", "--silent"])
    assert (args.command, args.path, args.sensor, args.max_frames) == ("run", Path("seq"), "rgbd", 5)
    assert (args.out, args.seed, args.config, args.silent) == (Path("o"), 3, Path("c.json"), True)
    args = cli.build_parser().parse_args(["run", "seq", "--sensor", "rgbd"])
    assert args.out is None and args.max_frames is None and not args.silent


@pytest.mark.parametrize("argv", [
    ["run", "seq", "--sensor", "lidar"],
    ["run", "seq"],
    ["run", "seq", "--sensor", "rgbd", "--max-frames", "0"],
    ["eval", "ate", "a.txt"],
    ["eval", "ate", "a.txt", "b.txt", "--align", "affine"],
    ["eval", "apples", "a.txt", "b.txt"],
])
def test_bad_arguments_are_argparse_errors(argv, capsys):
    with pytest.raises(SystemExit) as exit_info:
        cli.build_parser().parse_args(argv)
    assert exit_info.value.code == 2


def test_unknown_sensor(tmp_path, capsys):
    with pytest.raises(SystemExit) as exit_info:
        cli.main(["run", str(tmp_path), "--sensor", "lidar"])
    assert exit_info.value.code == 2
    assert "invalid choice: 'lidar'" in capsys.readouterr().err
    with pytest.raises(ValueError, match="unknown sensor 'lidar'"):
        pipeline.run_sequence(None, {}, sensor="lidar")


def test_inertial_sensor_needs_an_imu(tum_desk):
    with pytest.raises(ValueError, match="sensor 'rgbd-inertial' needs an IMU: .* has no imu"):
        pipeline.run_sequence(TumSequence(tum_desk), {}, sensor="rgbd-inertial", progress=False)


def test_eval_parser_defaults():
    args = cli.build_parser().parse_args(["eval", "ate", "ref.txt", "est.txt"])
    assert (args.metric, args.align, args.format, args.max_diff) == ("ate", "se3", "tum", 0.01)
    args = cli.build_parser().parse_args(["eval", "rpe", "r", "e", "--delta", "3"])
    assert (args.metric, args.align, args.delta) == ("rpe", "none", 3)


def test_eval_ate_prints_evo_number(groundtruth_dir, capsys):
    assert cli.main(["eval", "ate", str(groundtruth_dir / "freiburg1_xyz-groundtruth.txt"),
                     str(groundtruth_dir / "freiburg1_xyz-ORB_kf_mono.txt"),
                     "--align", "sim3"]) == 0
    out = capsys.readouterr().out
    assert "rmse   0.009755 m" in out and "32 pairs" in out


def test_missing_file_is_a_clean_error(tmp_path, capsys):
    assert cli.main(["eval", "ate", str(tmp_path / "ref.txt"), str(tmp_path / "est.txt")]) == 1
    assert "ref.txt" in capsys.readouterr().err


def test_python_dash_m_works(groundtruth_dir):
    ref = str(groundtruth_dir / "freiburg1_xyz-groundtruth.txt")
    est = str(groundtruth_dir / "freiburg1_xyz-rgbdslam.txt")
    proc = subprocess.run([sys.executable, "-m", "ferroslam", "eval", "rpe", ref, est],
                          capture_output=True, text=True, env={"PYTHONPATH": str(REPO / "python")})
    assert proc.returncode == 0, proc.stderr
    assert "784 pairs" in proc.stdout


def test_package_imports_without_native_module():
    assert ferroslam.__version__
    assert issubclass(ferroslam.SlamError, RuntimeError)
    assert ferroslam.metrics.ate and ferroslam.datasets.TumSequence


def _fake_factory(seq):
    return partial(FakeSlamSystem, groundtruth=seq.groundtruth())


def test_run_sequence_with_fake_core(tum_rpy):
    seq = TumSequence(tum_rpy)
    created = []

    def factory(*args, **kwargs):
        created.append(FakeSlamSystem(*args, groundtruth=seq.groundtruth(), **kwargs))
        return created[-1]

    result = pipeline.run_sequence(seq, {"n_features": 800, "ini_fast": 25, "seed": 1},
                                   max_frames=12, progress=False, system_factory=factory)
    # The extractor options go to the core, which owns every option; the extractor is built
    # from what the core holds.
    assert created[0].config == {"n_features": 800, "ini_fast": 25, "seed": 1}
    assert created[0].calls == pytest.approx(seq.timestamps[:12].tolist())
    assert result.frames == 12 and result.tracked_frames == 11
    assert result.states[0] == "not_initialized"
    assert len(result.trajectory) == 11 and len(result.keyframes) == 4
    assert result.ate_frames.rmse < 0.006  # nearest-pose lookup, SE(3) alignment removes T_map_gt
    assert result.rpe_frames.pairs == 10
    assert np.all(result.timings["extraction_ms"] > 0)
    np.testing.assert_array_equal(result.timings["tracking_ms"], [1.0] + [2.0] * 11)
    summary = result.summary()
    json.dumps(summary)
    assert summary["tracked_frames"] == 11 and summary["timing_ms"]["frame_ms"]["median"] > 0


def test_cli_run_writes_outputs(tum_desk, tmp_path, monkeypatch, capsys):
    seq = TumSequence(tum_desk)
    monkeypatch.setattr(session, "_core_system", _fake_factory(seq))
    config = tmp_path / "config.json"
    config.write_text(json.dumps({"n_features": 500, "track_feature_range": [50, 100]}))
    out = tmp_path / "out"
    assert cli.main(["run", str(tum_desk), "--sensor", "rgbd", "--config", str(config),
                     "--out", str(out), "--seed", "4", "--silent"]) == 0
    assert capsys.readouterr().out == ""
    traj = io.read_tum_trajectory(out / "trajectory.txt")
    assert len(traj) == 8
    assert len(io.read_tum_trajectory(out / "keyframes.txt")) == 3
    assert (out / "trajectory_top.png").stat().st_size > 1000
    results = json.loads((out / "results.json").read_text())
    assert results["config"] == {"n_features": 500, "track_feature_range": [50, 100], "seed": 4}
    assert results["metrics"]["ate_frames"]["rmse"] < 0.01
    assert cli.main(["run", str(tum_desk), "--sensor", "rgbd", "--out", str(out),
                     "--max-frames", "4"]) == 0
    printed = capsys.readouterr().out
    assert "tracked frames  3/4" in printed and "ATE frames" in printed and "p95" in printed


def test_cli_run_reports_bad_config(tum_desk, tmp_path, monkeypatch, capsys):
    seq = TumSequence(tum_desk)
    monkeypatch.setattr(session, "_core_system", _fake_factory(seq))
    config = tmp_path / "config.json"
    config.write_text('{"warp_speed": 9}')
    assert cli.main(["run", str(tum_desk), "--sensor", "rgbd", "--config", str(config),
                     "--out", str(tmp_path / "o"), "--silent"]) == 1
    assert "warp_speed" in capsys.readouterr().err
    config.write_text("[1, 2]")
    assert cli.main(["run", str(tum_desk), "--sensor", "rgbd", "--config", str(config),
                     "--silent"]) == 1
    assert "JSON object" in capsys.readouterr().err
    assert cli.main(["run", str(tmp_path / "nowhere"), "--sensor", "rgbd", "--silent"]) == 1
    assert "nowhere" in capsys.readouterr().err


@pytest.mark.parametrize("argv", [[], ["demo"], ["run"], ["eval"], ["eval", "ate"],
                                  ["eval", "rpe"], ["download"]])
def test_every_help_is_complete(argv, capsys):
    with pytest.raises(SystemExit) as exit_info:
        cli.main(argv + ["--help"])
    assert exit_info.value.code == 0
    text = capsys.readouterr().out
    assert text.startswith("usage: ferroslam") and "show this help message" in text
    for sub in ("demo", "run", "eval", "download") if not argv else ():
        assert sub in text
    if argv == ["run"]:
        assert "dataset layouts" in text and "calib.txt" in text and "map.ply" in text
    if argv == ["download"]:
        assert "V1_01_easy" in text and "freiburg1_xyz" in text and "--to DIR" in text


def test_wrong_path_says_what_was_expected(tmp_path, capsys):
    assert cli.main(["run", str(tmp_path / "nowhere"), "--sensor", "rgbd"]) == 1
    err = capsys.readouterr().err
    assert "nowhere" in err and "rgb.txt (TUM)" in err
    assert cli.main(["run", str(tmp_path), "--sensor", "rgbd"]) == 1
    assert "cannot detect the dataset layout" in capsys.readouterr().err
