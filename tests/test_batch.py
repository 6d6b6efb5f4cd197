"""``ferroslam batch``: SPEC expansion and errors, the table and summary writers, and a real
local Ray cluster (2 CPUs, 127.0.0.1) running short runs of the shared data."""

from __future__ import annotations

import csv
import importlib.util
import json
import os
from pathlib import Path

import pytest
from conftest import require_data

from ferroslam import batch, cli

EXAMPLE = json.loads(batch.SPEC_EXAMPLE)


def _require_ray() -> None:
    """Skip locally without Ray; CI installs ``ferroslam[batch]``, so there it must be. Ray is
    looked up, not imported: ``ferroslam.batch`` must import it first to keep a local
    instance on 127.0.0.1."""
    if importlib.util.find_spec("ray") is not None:
        return
    if os.environ.get("CI", "").lower() in ("1", "true", "yes"):
        pytest.fail("Ray is missing: pip install 'ferroslam[batch]'")
    pytest.skip("Ray is missing: pip install 'ferroslam[batch]'")


def test_example_spec_expands_defaults_overrides_grid_and_repeats(tmp_path):
    runs = batch.expand_spec(EXAMPLE, tmp_path, "spec.json")
    assert len(runs) == 3 + 3 * 5
    first, swept = runs[:3], runs[3:]
    assert [r.repeat for r in first] == [0, 1, 2]
    assert first[0].path == tmp_path / "data" / "rgbd_dataset_freiburg1_xyz"
    assert first[0].options == {"n_features": 1200} and first[0].max_frames is None
    assert [r.options["n_features"] for r in swept] == [1000] * 5 + [1500] * 5 + [2000] * 5
    assert all(r.options["depth_threshold"] == 35 for r in swept)
    assert swept[0].sensor == "stereo-inertial" and swept[-1].repeat == 4
    assert len({r.folder for r in runs}) == len(runs)  # one folder per run
    again = batch.expand_spec(EXAMPLE, tmp_path, "spec.json")
    assert [r.folder for r in again] == [r.folder for r in runs]  # stable across calls


def test_grid_points_cross_every_key(tmp_path):
    spec = {"max_frames": 10, "runs": [{"sequence": "/s", "sensor": "mono", "max_frames": 5,
                                        "grid": {"n_levels": [6, 8],
                                                 "scale_factor": [1.1, 1.2, 1.3]}}]}
    runs = batch.expand_spec(spec, tmp_path, "s.json")
    assert [(r.options["n_levels"], r.options["scale_factor"]) for r in runs] == [
        (6, 1.1), (6, 1.2), (6, 1.3), (8, 1.1), (8, 1.2), (8, 1.3)]
    assert {r.max_frames for r in runs} == {5} and runs[0].path == Path("/s")


@pytest.mark.parametrize("spec, message", [
    ([], r"the SPEC must be a mapping"),
    ({"runs": []}, r"'runs' must be a non-empty list"),
    ({"runs": [{"sequence": "s", "sensor": "rgbd"}], "repeat": 2}, r"unknown key 'repeat' in the SPEC"),
    ({"runs": [{"sequence": "s", "sensor": "lidar"}]}, r"runs\[0\]\.sensor must be one of"),
    ({"runs": [{"sensor": "rgbd"}]}, r"runs\[0\]\.sequence must be a folder path"),
    ({"runs": [{"sequence": "s", "sensor": "rgbd", "repeats": 0}]}, r"runs\[0\]\.repeats must be a positive"),
    ({"max_frames": "all", "runs": [{"sequence": "s", "sensor": "rgbd"}]}, r"max_frames must be a positive"),
    ({"runs": [{"sequence": "s", "sensor": "rgbd", "grid": {"n_features": 1000}}]},
     r"runs\[0\]\.grid\.n_features must be a non-empty list"),
    ({"options": {"sensor": "mono"}, "runs": [{"sequence": "s", "sensor": "rgbd"}]}, r"options\.sensor"),
    ({"runs": [{"sequence": "s", "sensor": "rgbd"}, {"sequence": "s", "sensor": "rgbd"}]},
     r"s \(rgbd, options \{\}\) is listed twice"),
])
def test_spec_errors_name_the_file_and_the_key(tmp_path, spec, message):
    with pytest.raises(ValueError, match=r"^bad\.json: .*" + message):
        batch.expand_spec(spec, tmp_path, "bad.json")


@pytest.mark.parametrize("options, grid, error, message", [
    ({"n_features": 1000}, {"mapping_thread": ["no"]}, TypeError,
     r"runs\[0\]: option 'mapping_thread': expected True or False, got 'no'"),
    ({"n_featurez": 1000}, {}, ValueError, r"runs\[0\]: unknown option 'n_featurez'"),
    ({}, {"scale_factor": [1.2, float("nan")]}, ValueError, r"runs\[0\]: option 'scale_factor'"),
    ({"gravity_magnitude": 9.81}, {}, ValueError, r"runs\[0\]: .*'gravity_magnitude'"),
])
def test_spec_options_go_through_the_option_schema(tmp_path, options, grid, error, message):
    # Every grid point is checked before any run starts (the last case: an IMU option of a
    # run without an IMU).
    spec = {"runs": [{"sequence": "s", "sensor": "rgbd", "options": options, "grid": grid}]}
    with pytest.raises(error, match=r"^bad\.json: " + message):
        batch.expand_spec(spec, tmp_path, "bad.json")


def test_yaml_and_json_specs_read_alike(tmp_path):
    (tmp_path / "spec.json").write_text(batch.SPEC_EXAMPLE)
    (tmp_path / "spec.yaml").write_text(batch.SPEC_EXAMPLE)  # YAML reads JSON too
    from_json = batch.load_spec(tmp_path / "spec.json")
    assert [r.folder for r in batch.load_spec(tmp_path / "spec.yaml")] == [
        r.folder for r in from_json]
    with pytest.raises(FileNotFoundError, match="SPEC file not found"):
        batch.load_spec(tmp_path / "missing.yaml")


def test_cli_reports_a_spec_error_with_exit_status_1(tmp_path, capsys):
    spec = tmp_path / "spec.json"
    spec.write_text('{"runs": [{"sequence": "s", "sensor": "rgbd", "frames": 3}]}')
    assert cli.main(["batch", str(spec), "--out", str(tmp_path / "out")]) == 1
    err = capsys.readouterr().err
    assert err.startswith("ferroslam: error: ") and f"{spec}: unknown key 'frames'" in err


def test_named_datasets_are_fetched_once_and_a_failed_fetch_fails_its_runs(tmp_path):
    desk = require_data("tum", "rgbd_dataset_freiburg1_desk")
    runs = batch.expand_spec(
        {"repeats": 2, "max_frames": 3,
         "runs": [{"sequence": "tum:freiburg1_desk", "sensor": "rgbd"},
                  {"sequence": "kitti:00", "sensor": "stereo"}]}, tmp_path, "spec.json")
    calls = []

    def fetch(dataset, name, dest, progress=True):
        calls.append((dataset, name, dest))
        if dataset == "kitti":
            raise batch.DownloadError("KITTI needs an account: download it by hand")
        return desk

    runs = batch.fetch_named_sequences(runs, tmp_path / "datasets", False, fetch=fetch)
    assert sorted(calls) == [("kitti", "00", tmp_path / "datasets"),
                             ("tum", "freiburg1_desk", tmp_path / "datasets")]
    assert [r.path for r in runs[:2]] == [desk, desk] and not runs[0].unavailable
    assert runs[2].unavailable.startswith("kitti:00: KITTI needs an account")
    row = batch.execute_run(runs[2], tmp_path / "out")
    assert row["status"] == "failed" and "KITTI needs an account" in row["error"]
    assert batch.execute_run(runs[0], tmp_path / "out")["status"] == "ok"


def test_batch_arguments():
    args = cli.build_parser().parse_args(["batch", "spec.yaml", "--out", "o"])
    assert (args.spec, args.out, args.address, args.cpus_per_run) == (
        Path("spec.yaml"), Path("o"), None, 1)
    args = cli.build_parser().parse_args(
        ["batch", "s.json", "--out", "o", "--address", "ray://head:10001", "--cpus-per-run", "2",
         "--num-cpus", "4", "--retry-failed", "--silent"])
    assert (args.address, args.cpus_per_run, args.num_cpus) == ("ray://head:10001", 2, 4)
    assert args.retry_failed and args.silent


def _row(repeat: int, ate_m, status: str = "ok", **options) -> dict:
    return {"sequence": "seq", "sensor": "rgbd", "max_frames": 30, "repeat": repeat,
            "options": options, "run_dir": f"seq/repeat_{repeat}", "status": status,
            "error": "" if status == "ok" else "boom", "tracked_frames": 30, "frames": 30,
            "ate_rmse_m": ate_m}


def test_table_has_one_column_per_option_key_and_summary_median_and_range(tmp_path):
    rows = [_row(0, 0.01, n_features=1000), _row(1, 0.03, n_features=1000),
            _row(2, 0.02, n_features=1000), _row(0, None, "failed", depth_threshold=35)]
    batch.write_table(rows, tmp_path / "results.csv")
    with (tmp_path / "results.csv").open() as f:
        table = list(csv.DictReader(f))
    assert [t["n_features"] for t in table] == ["1000"] * 3 + [""]
    assert table[3]["depth_threshold"] == "35" and table[3]["ate_rmse_m"] == ""
    assert table[1]["scale_error"] == ""  # a figure the row lacks: an empty cell
    batch.write_summary(rows, tmp_path / "summary.md")
    summary = (tmp_path / "summary.md").read_text()
    assert "| seq | rgbd | n_features=1000 | 30 | 3/3 | 30 [30, 30] | 0.0200 [0.0100, 0.0300] |" in summary
    assert "| seq | rgbd | depth_threshold=35 | 30 | 0/1 | - |" in summary
    assert "- `seq/repeat_0` (failed): boom" in summary


def test_local_ray_instance_binds_to_loopback():
    _require_ray()
    with batch._ray_session(None, 1) as ray:
        assert ray.get_runtime_context().gcs_address.startswith("127.0.0.1:")
        assert [node["NodeManagerAddress"] for node in ray.nodes()] == ["127.0.0.1"]
    assert not ray.is_initialized()


def test_batch_on_a_local_cluster_isolates_failures_and_skips_done_runs(tmp_path, capsys):
    """Two sequences x two repeats and one missing folder: five rows, one failed, exit 1;
    the second call runs nothing and writes the same table."""
    _require_ray()
    spec = {"repeats": 2, "max_frames": 30, "runs": [
        {"sequence": str(require_data("tum", "rgbd_dataset_freiburg1_rpy")), "sensor": "rgbd"},
        {"sequence": str(require_data("euroc", "V1_01_easy_micro")), "sensor": "stereo",
         "max_frames": 20, "options": {"n_features": 800}},
        {"sequence": "no_such_sequence", "sensor": "mono", "repeats": 1},
    ]}
    (tmp_path / "spec.json").write_text(json.dumps(spec))
    out = tmp_path / "out"
    argv = ["batch", str(tmp_path / "spec.json"), "--out", str(out), "--num-cpus", "2", "--silent"]
    assert cli.main(argv) == 1
    assert "no_such_sequence" in capsys.readouterr().err
    with (out / "results.csv").open() as f:
        table = list(csv.DictReader(f))
    assert [t["status"] for t in table] == ["ok"] * 4 + ["failed"]
    assert [(t["sensor"], t["repeat"], t["frames"]) for t in table[:4]] == [
        ("rgbd", "0", "30"), ("rgbd", "1", "30"), ("stereo", "0", "20"), ("stereo", "1", "20")]
    assert [t["n_features"] for t in table] == ["", "", "800", "800", ""]
    assert "FileNotFoundError" in table[4]["error"] and table[4]["ate_rmse_m"] == ""
    for t in table[:4]:
        assert int(t["tracked_frames"]) >= 15 and float(t["ate_rmse_m"]) < 0.05
        assert float(t["peak_rss_mb"]) > 0 and float(t["frame_ms_p95"]) > 0
        assert (out / t["run_dir"] / "trajectory.txt").is_file()
        assert json.loads((out / t["run_dir"] / "results.json").read_text())["frames"] == int(
            t["frames"])
    summary = (out / "summary.md").read_text()
    assert summary.count("| 2/2 |") == 2 and "| 0/1 |" in summary

    first_table = (out / "results.csv").read_text()
    rows_written = {p: p.stat().st_mtime_ns for p in out.glob("*/*/row.json")}
    assert len(rows_written) == 5
    assert cli.main(argv) == 1
    assert (out / "results.csv").read_text() == first_table
    assert {p: p.stat().st_mtime_ns for p in out.glob("*/*/row.json")} == rows_written
