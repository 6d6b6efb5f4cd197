"""Every failure of the ``ferroslam`` command is one line ``ferroslam: error: ...`` with exit
status 1 (argparse's usage errors: their own form, status 2); ``--traceback`` or
``FERROSLAM_TRACEBACK=1`` adds the stack (issue 53)."""

from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path

import pytest

from ferroslam import batch, cli

REPO = Path(__file__).resolve().parents[1]


def _fails(argv: list[str], capsys) -> str:
    """The one line ``main(argv)`` prints, after checking the exit status is 1."""
    assert cli.main(argv) == 1
    captured = capsys.readouterr()
    assert captured.err.count("\n") == 1, captured.err
    assert captured.err.startswith("ferroslam: error: ")
    return captured.err.rstrip("\n")


def _spec(tmp_path: Path, spec: object, name: str = "spec.json") -> Path:
    path = tmp_path / name
    path.write_text(json.dumps(spec) if name.endswith(".json") else spec)
    return path


def test_config_option_of_the_vslam_objects(tum_desk, tmp_path, capsys):
    config = _spec(tmp_path, {"threaded": True}, "config.json")
    line = _fails(["run", str(tum_desk), "--sensor", "rgbd", "--config", str(config),
                   "--out", str(tmp_path / "o"), "--silent"], capsys)
    assert line.startswith("ferroslam: error: option 'threaded' is taken by the vSLAM objects")
    assert not (tmp_path / "o").exists()  # failed before any output: no folder, no partial-*


def test_no_stereo_is_for_a_rig(tum_desk, tmp_path, capsys):
    line = _fails(["run", str(tum_desk), "--sensor", "rgbd", "--no-stereo",
                   "--out", str(tmp_path / "o"), "--silent"], capsys)
    assert line == ("ferroslam: error: --no-stereo is for --sensor rig (a stereo pair left "
                    "raw), not --sensor rgbd")
    assert not (tmp_path / "o").exists()


def test_deeply_nested_config_and_spec(tmp_path, capsys):
    deep = tmp_path / "deep.json"
    deep.write_text("[" * 100_000 + "]" * 100_000)
    line = _fails(["run", str(tmp_path), "--sensor", "rgbd", "--config", str(deep)], capsys)
    assert line.startswith(f"ferroslam: error: {deep}: nested") and "deep" in line
    assert _fails(["batch", str(deep), "--out", str(tmp_path / "o")], capsys) == (
        f"ferroslam: error: {deep}: nested deeper than 32 levels")
    yaml_spec = tmp_path / "deep.yaml"  # block style, which bracket counting does not see
    yaml_spec.write_text("runs:\n" + "".join(" " * (i + 1) + "a:\n" for i in range(1300)))
    assert _fails(["batch", str(yaml_spec), "--out", str(tmp_path / "o")], capsys) == (
        f"ferroslam: error: {yaml_spec}: nested too deeply")


def test_huge_camera_index(tmp_path, capsys):
    assert _fails(["run", "camera:99999999999999999999", "--sensor", "mono"], capsys) == (
        "ferroslam: error: camera:99999999999999999999: camera index out of range "
        "(0..2147483647)")


def test_decode_errors_name_the_file(tmp_path, capsys):
    latin = tmp_path / "latin.json"
    latin.write_bytes(b'{"a": "\xe9"}')
    line = _fails(["batch", str(latin), "--out", str(tmp_path / "o")], capsys)
    assert line == f"ferroslam: error: {latin}: not UTF-8 text (byte 7)"
    ref = tmp_path / "ref.txt"
    ref.write_bytes(b"1 2 3 4 5 6 7 \xff\n")
    assert _fails(["eval", "ate", str(ref), str(ref)], capsys) == (
        f"ferroslam: error: {ref}: not a UTF-8 text file")


@pytest.mark.parametrize("spec, message", [
    ({"repeats": 100_000_000, "runs": [{"sequence": "s", "sensor": "rgbd"}]},
     "runs[0] expands to 100000000 runs (grid points x repeats); a SPEC may have at most "
     "10000 runs in all"),
    ({"runs": [{"sequence": "s", "sensor": "rgbd"},
               {"sequence": "s", "sensor": "mono",
                "grid": {k: list(range(10)) for k in "abcd"}}]},
     "runs[1] expands to 10000 runs (grid points x repeats); a SPEC may have at most "
     "10000 runs in all"),
])
def test_spec_run_bound_before_expanding(tmp_path, capsys, spec, message):
    path = _spec(tmp_path, spec)
    assert _fails(["batch", str(path), "--out", str(tmp_path / "o")], capsys) == (
        f"ferroslam: error: {path}: {message}")


def test_run_folders_do_not_collide(tmp_path):
    grid = {"n_features": list(range(1000, 3000))}
    runs = batch.expand_spec({"runs": [{"sequence": "seq", "sensor": "mono", "grid": grid}]},
                             tmp_path, "spec")
    folders = {run.folder for run in runs}
    assert len(folders) == len(runs) == 2000
    assert all(len(f.split("/")[0].rsplit("_", 1)[1]) == 64 for f in folders)  # sha256 hex
    assert runs[0].folder.startswith("seq_mono_")


def test_row_json_without_options(tmp_path, capsys):
    spec = _spec(tmp_path, {"runs": [{"sequence": "seq", "sensor": "mono"}]})
    (run,) = batch.load_spec(spec)
    out = tmp_path / "o"
    row = out / run.folder / "row.json"
    row.parent.mkdir(parents=True)
    row.write_text(json.dumps({"sequence": "seq", "sensor": "mono", "max_frames": None,
                               "repeat": 0, "status": "ok", "run_dir": run.folder}))
    assert _fails(["batch", str(spec), "--out", str(out)], capsys) == (
        f"ferroslam: error: {row.resolve()}: not a run row of ferroslam batch (no 'options')")


def test_any_exception_is_one_line_and_traceback_on_request(tmp_path, capsys, monkeypatch):
    def boom(args):
        raise RuntimeError("the core said\nsomething on two lines")

    monkeypatch.setattr(cli, "_cmd_eval", boom)
    argv = ["eval", "ate", "a", "b"]
    assert _fails(argv, capsys) == ("ferroslam: error: the core said something on two lines")
    assert cli.main(["--traceback", *argv]) == 1
    err = capsys.readouterr().err
    assert "Traceback (most recent call last)" in err and "in boom" in err
    assert err.endswith("ferroslam: error: the core said something on two lines\n")
    monkeypatch.setenv("FERROSLAM_TRACEBACK", "1")
    assert cli.main(argv) == 1
    assert "Traceback (most recent call last)" in capsys.readouterr().err


def test_key_error_says_what_it_is(capsys, monkeypatch):
    def missing(args):
        raise KeyError("rate_hz")

    monkeypatch.setattr(cli, "_cmd_eval", missing)
    assert _fails(["eval", "ate", "a", "b"], capsys) == "ferroslam: error: KeyError: 'rate_hz'"


def test_usage_errors_keep_argparse_form(capsys):
    with pytest.raises(SystemExit) as exit_info:
        cli.main(["run", "seq", "--sensor", "lidar"])
    assert exit_info.value.code == 2
    assert "ferroslam run: error: argument --sensor: invalid choice: 'lidar'" in (
        capsys.readouterr().err)


def test_subprocess_prints_one_line(tmp_path):
    deep = tmp_path / "deep.json"
    deep.write_text("{\"a\": " * 50_000 + "1" + "}" * 50_000)
    proc = subprocess.run([sys.executable, "-m", "ferroslam", "batch", str(deep), "--out",
                           str(tmp_path / "o")], capture_output=True, text=True,
                          env={"PYTHONPATH": str(REPO / "python")}, timeout=120)
    assert proc.returncode == 1
    assert proc.stderr == f"ferroslam: error: {deep}: nested deeper than 32 levels\n"


def test_vocab_export_into_a_fifo_is_refused(tmp_path, capsys):
    fifo = tmp_path / "ORBvoc.txt"
    os.mkfifo(fifo)
    assert _fails(["vocab", "export-dbow2", str(fifo)], capsys) == (
        f"ferroslam: error: {fifo}: is a FIFO, not a regular file; refusing to replace it")
    assert [p.name for p in tmp_path.iterdir()] == ["ORBvoc.txt"]
