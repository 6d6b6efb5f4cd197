"""Outputs never destroy data (issue 53): one writer (``ferroslam._files``) for every file,
run folders staged and moved into ``--out`` only when a run ends, special files refused."""

from __future__ import annotations

import json
import os
import socket
import stat
from functools import partial
from pathlib import Path

import numpy as np
import pytest
from hypothesis import HealthCheck, given
from hypothesis import strategies as st

from ferroslam import Camera, MonoVSlam, cli, io, session
from ferroslam._files import StagedFolder, atomic_output, read_bounded_text, regular_file, \
    write_text
from ferroslam.datasets import TumSequence
from ferroslam.export import write_colmap_model, write_ply
from ferroslam.vocabulary import DEFAULT_VOCABULARY_PATH, default_vocabulary, save_vocabulary

from fake_core import FakeSlamSystem
from fuzzing import fuzz

CAMERA = Camera(500.0, 500.0, 320.0, 240.0)


def _fifo(path: Path) -> Path:
    os.mkfifo(path)
    return path


def _socket(path: Path) -> Path:
    s = socket.socket(socket.AF_UNIX)
    s.bind(str(path))
    s.close()
    return path


def _device(path: Path) -> Path:
    # A node of /dev/null's kind in tmp_path (needs root): the real /dev/null is never used.
    os.mknod(path, stat.S_IFCHR | 0o666, os.makedev(1, 3))
    return path


SPECIAL = [("a FIFO", _fifo), ("a socket", _socket)]
if os.geteuid() == 0:
    SPECIAL.append(("a character device", _device))


def _snapshot(folder: Path) -> dict:
    """Every entry below ``folder``: kind and, for regular files, content."""
    out = {}
    for p in sorted(folder.rglob("*")):
        st_ = os.lstat(p)
        out[str(p.relative_to(folder))] = (stat.S_IFMT(st_.st_mode),
                                           p.read_bytes() if stat.S_ISREG(st_.st_mode) else None)
    return out


# -- the writer -------------------------------------------------------------------------------
@pytest.mark.parametrize("kind, make", SPECIAL)
def test_special_target_is_refused_and_kept(tmp_path, kind, make):
    target = make(tmp_path / "map.bin")
    mode = os.lstat(target).st_mode
    with pytest.raises(ValueError, match=f"map.bin: is {kind}, not a regular file; refusing"):
        write_text(target, "data")
    assert os.lstat(target).st_mode == mode  # the node is still there, same kind
    assert sorted(p.name for p in tmp_path.iterdir()) == ["map.bin"]  # no temp file left


def test_directory_target_is_refused(tmp_path):
    (tmp_path / "out.ply").mkdir()
    with pytest.raises(IsADirectoryError, match="out.ply: is a directory, not a file"):
        write_ply(tmp_path / "out.ply", np.zeros((2, 3)))


def test_parent_that_is_a_file_is_named(tmp_path):
    (tmp_path / "f").write_text("x")
    with pytest.raises(NotADirectoryError, match="f: exists and is not a folder"):
        write_text(tmp_path / "f" / "g.txt", "y")


def test_symlink_at_target_is_replaced_not_followed(tmp_path):
    victim = tmp_path / "victim.txt"
    victim.write_text("keep me")
    link = tmp_path / "trajectory.txt"
    link.symlink_to(victim)
    io.write_tum_trajectory(link, np.array([0.0]), np.eye(4)[None])
    assert victim.read_text() == "keep me"
    assert not link.is_symlink() and len(io.read_tum_trajectory(link)) == 1


def test_failed_write_keeps_the_old_file_and_leaves_no_temp(tmp_path):
    target = tmp_path / "results.json"
    target.write_text("old")
    with pytest.raises(RuntimeError, match="disk on fire"):
        with atomic_output(target) as tmp:
            tmp.write_text("half")
            raise RuntimeError("disk on fire")
    assert target.read_text() == "old"
    assert [p.name for p in tmp_path.iterdir()] == ["results.json"]


def test_missing_parents_are_created_and_mode_is_the_umask(tmp_path):
    path = write_text(tmp_path / "a" / "b" / "c.txt", "hello")
    assert path.read_text() == "hello"
    umask = os.umask(0)
    os.umask(umask)
    assert stat.S_IMODE(path.stat().st_mode) == 0o666 & ~umask


@pytest.mark.parametrize("kind, make", SPECIAL)
def test_save_map_refuses_a_special_file(tmp_path, kind, make):
    target = make(tmp_path / "room.map")
    with MonoVSlam(CAMERA, threaded=False, vocabulary=None) as vslam:
        with pytest.raises(ValueError, match=f"room.map: is {kind}"):
            vslam.save_map(target)
    assert not stat.S_ISREG(os.lstat(target).st_mode)


def test_save_map_replaces_a_symlink_and_round_trips(tmp_path):
    victim = tmp_path / "victim.txt"
    victim.write_text("keep me")
    (tmp_path / "room.map").symlink_to(victim)
    with MonoVSlam(CAMERA, threaded=False, vocabulary=None) as vslam:
        vslam.save_map(tmp_path / "room.map")
        vslam.load_map(tmp_path / "room.map")
    assert victim.read_text() == "keep me"
    assert not (tmp_path / "room.map").is_symlink()


def test_load_map_refuses_a_fifo_without_blocking(tmp_path):
    fifo = _fifo(tmp_path / "room.map")
    with MonoVSlam(CAMERA, threaded=False, vocabulary=None) as vslam:
        with pytest.raises(ValueError, match="room.map: is a FIFO, expected a regular map file"):
            vslam.load_map(fifo)
        with pytest.raises(IsADirectoryError, match="is a directory, expected a map file"):
            vslam.load_map(tmp_path)


def test_readers_refuse_special_files(tmp_path):
    fifo = _fifo(tmp_path / "traj.txt")
    with pytest.raises(ValueError, match="traj.txt: is a FIFO, expected a regular TUM"):
        io.read_tum_trajectory(fifo)
    with pytest.raises(ValueError, match="traj.txt: is a FIFO"):
        read_bounded_text(fifo)
    with pytest.raises(FileNotFoundError, match="file not found: .*nothing"):
        regular_file(tmp_path / "nothing")
    big = tmp_path / "big.json"
    big.write_text("x" * 101)
    with pytest.raises(ValueError, match="big.json: 101 bytes, more than the 100"):
        read_bounded_text(big, 100)
    latin = tmp_path / "latin.json"
    latin.write_bytes(b'{"a": "\xe9"}')
    with pytest.raises(ValueError, match="latin.json: not UTF-8 text"):
        read_bounded_text(latin)


def test_vocabulary_save_refuses_a_fifo(tmp_path):
    fifo = _fifo(tmp_path / "voc.txt")
    with pytest.raises(ValueError, match="voc.txt: is a FIFO"):
        save_vocabulary(default_vocabulary(), fifo, dbow2_text=True)
    assert stat.S_ISFIFO(os.lstat(fifo).st_mode)


def test_core_writers_called_directly_refuse_special_files(tmp_path):
    """``ferroslam._core`` writes through the core's one writer (``ferroslam-files``): the
    same refusals as the Python writer, for a caller that bypasses the package."""
    from ferroslam import _core

    fifo = _fifo(tmp_path / "target")
    voc = _core.Vocabulary.load(str(DEFAULT_VOCABULARY_PATH))
    for save in (voc.save, voc.save_dbow2_text,
                 _core.SlamSystem(517.3, 516.5, 318.6, 255.3, [], 640, 480).save_map):
        with pytest.raises(ValueError, match="target: .*is a FIFO, not a regular file; refusing"):
            save(str(fifo))
        assert stat.S_ISFIFO(os.lstat(fifo).st_mode)
    with pytest.raises(ValueError, match="map file .*target: is a FIFO, expected a regular map file"):
        _core.SlamSystem(517.3, 516.5, 318.6, 255.3, [], 640, 480).load_map(str(fifo))
    with pytest.raises(ValueError, match="is a FIFO, expected a regular vocabulary file"):
        _core.Vocabulary.load(str(fifo))
    victim = tmp_path / "victim.txt"
    victim.write_text("keep me")
    (tmp_path / "voc.bin").symlink_to(victim)
    voc.save(str(tmp_path / "voc.bin"))
    assert victim.read_text() == "keep me" and not (tmp_path / "voc.bin").is_symlink()
    assert sorted(p.name for p in tmp_path.iterdir()) == ["target", "victim.txt", "voc.bin"]


def test_colmap_folder_link_is_not_written_through(tmp_path):
    elsewhere = tmp_path / "elsewhere"
    elsewhere.mkdir()
    out = tmp_path / "out"
    out.mkdir()
    (out / "colmap").symlink_to(elsewhere)
    with StagedFolder(out) as stage:
        write_colmap_model(stage.path / "colmap", CAMERA, [0], np.eye(4)[None], np.zeros((1, 3)))
    assert list(elsewhere.iterdir()) == []
    assert not (out / "colmap").is_symlink()
    assert sorted(p.name for p in (out / "colmap").iterdir()) == [
        "cameras.txt", "images.txt", "points3D.txt"]


# -- staged run folders ---------------------------------------------------------------------
def test_staged_folder_failure_keeps_previous_results(tmp_path):
    out = tmp_path / "out"
    with StagedFolder(out) as stage:
        write_text(stage.path / "trajectory.txt", "complete")
    with pytest.raises(RuntimeError, match="frame 0 is corrupt"):
        with StagedFolder(out) as stage:
            write_text(stage.path / "trajectory.txt", "")
            raise RuntimeError("frame 0 is corrupt")
    assert (out / "trajectory.txt").read_text() == "complete"
    assert stage.partial.parent == out and stage.partial.name.startswith("partial-")
    assert (stage.partial / "trajectory.txt").read_text() == ""
    assert sorted(p.name for p in tmp_path.iterdir()) == ["out"]
    assert not [p for p in out.iterdir() if p.name.startswith(".staging")]


def test_staged_folder_stages_inside_out_and_leaves_no_empty_folder(tmp_path):
    out = tmp_path / "volume"
    with pytest.raises(RuntimeError, match="no frame"):
        with StagedFolder(out) as stage:
            # inside --out: a --out that is a mount point gets renames, not cross-device moves
            assert stage.path.parent == out and os.stat(stage.path).st_dev == os.stat(out).st_dev
            raise RuntimeError("no frame")
    assert stage.partial is None and not out.exists()
    out.mkdir()
    with pytest.raises(RuntimeError, match="no frame"):
        with StagedFolder(out):
            raise RuntimeError("no frame")
    assert out.is_dir() and list(out.iterdir()) == []  # the user's folder stays


def test_staged_folder_refuses_a_fifo_entry_and_keeps_the_results(tmp_path):
    out = tmp_path / "out"
    out.mkdir()
    _fifo(out / "results.json")
    with pytest.raises(ValueError, match=r"results.json: is a FIFO.*the results are in .*partial-"):
        with StagedFolder(out) as stage:
            write_text(stage.path / "results.json", "{}")
    assert stat.S_ISFIFO(os.lstat(out / "results.json").st_mode)
    assert (stage.partial / "results.json").read_text() == "{}"


def _fake_factory(seq):
    return partial(FakeSlamSystem, groundtruth=seq.groundtruth())


def test_cli_run_never_writes_through_links_in_out(tum_desk, tmp_path, monkeypatch, capsys):
    monkeypatch.setattr(session, "_core_system", _fake_factory(TumSequence(tum_desk)))
    out, elsewhere, victim = tmp_path / "out", tmp_path / "elsewhere", tmp_path / "victim.txt"
    out.mkdir()
    elsewhere.mkdir()
    victim.write_text("keep me")
    (out / "trajectory.txt").symlink_to(victim)
    (out / "colmap").symlink_to(elsewhere)
    assert cli.main(["run", str(tum_desk), "--sensor", "rgbd", "--out", str(out),
                     "--silent"]) == 0
    assert victim.read_text() == "keep me" and list(elsewhere.iterdir()) == []
    assert not (out / "trajectory.txt").is_symlink() and not (out / "colmap").is_symlink()
    assert len(io.read_tum_trajectory(out / "trajectory.txt")) == 8


def _corrupt_copy(src: Path, dest: Path, bad_frame: int) -> Path:
    """A TUM folder linking to ``src``'s files, colour frame ``bad_frame`` replaced by junk."""
    dest.mkdir()
    for name in ("rgb.txt", "depth.txt", "groundtruth.txt", "depth"):
        (dest / name).symlink_to(src / name)
    (dest / "rgb").mkdir()
    frames = sorted((src / "rgb").iterdir())
    for i, frame in enumerate(frames):
        if i == bad_frame:
            (dest / "rgb" / frame.name).write_bytes(b"not a png")
        else:
            (dest / "rgb" / frame.name).symlink_to(frame)
    return dest


def test_failed_run_keeps_previous_results_and_puts_partial_beside(tum_desk, tmp_path,
                                                                     monkeypatch, capsys):
    monkeypatch.setattr(session, "_core_system", _fake_factory(TumSequence(tum_desk)))
    out = tmp_path / "out"
    assert cli.main(["run", str(tum_desk), "--sensor", "rgbd", "--out", str(out),
                     "--silent"]) == 0
    before = _snapshot(out)
    broken = _corrupt_copy(tum_desk, tmp_path / "rgbd_dataset_freiburg1_desk", bad_frame=3)
    assert cli.main(["run", str(broken), "--sensor", "rgbd", "--out", str(out),
                     "--silent"]) == 1
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and err.startswith("ferroslam: error: ")
    assert "the results of the 3 frames before it are in" in err and "partial-" in err
    (partial_dir,) = [p for p in out.iterdir() if p.name.startswith("partial-")]
    assert {k: v for k, v in _snapshot(out).items()
            if not k.startswith(partial_dir.name)} == before
    assert json.loads((partial_dir / "results.json").read_text())["frames"] == 3
    assert str(partial_dir) in err


def test_rerun_recording_into_a_folder_not_made_yet(tmp_path):
    from ferroslam.viewer import RerunLogger

    path = tmp_path / "run" / "rec.rrd"
    logger = RerunLogger(save_path=path)
    logger.log_map(np.zeros((4, 3)))
    assert not path.exists()  # recorded beside it, moved there by close()
    logger.close()
    assert path.stat().st_size > 100
    assert [p.name for p in path.parent.iterdir()] == ["rec.rrd"]
    with pytest.raises(ValueError, match="rec.fifo: is a FIFO"):
        RerunLogger(save_path=_fifo(tmp_path / "rec.fifo"))


# -- property: whatever is at the target, the writer succeeds or raises the documented error --
_KINDS = ["missing", "file", "dir", "fifo", "link_to_file", "link_to_dir", "dangling_link",
          "parent_is_file"]


@given(kind=st.sampled_from(_KINDS),
       name=st.text(st.characters(whitelist_categories=("L", "N"), whitelist_characters="._-"),
                    min_size=1, max_size=20).filter(lambda s: s not in (".", "..")),
       depth=st.integers(0, 3), fail=st.booleans())
@fuzz(60, deadline=2000, suppress_health_check=[HealthCheck.function_scoped_fixture])
def test_writer_property(tmp_path_factory, kind, name, depth, fail):
    root = tmp_path_factory.mktemp("prop")
    box, outside = root / "box", root / "outside"
    box.mkdir()
    outside.mkdir()
    (outside / "victim").write_text("keep")
    folder = box.joinpath(*[f"d{i}" for i in range(depth)])
    target = folder / name
    if kind != "missing":
        folder.mkdir(parents=True, exist_ok=True)
    if kind == "file":
        target.write_text("old")
    elif kind == "dir":
        target.mkdir()
    elif kind == "fifo":
        os.mkfifo(target)
    elif kind == "link_to_file":
        target.symlink_to(outside / "victim")
    elif kind == "link_to_dir":
        target.symlink_to(outside)
    elif kind == "dangling_link":
        target.symlink_to(outside / "nothing")
    elif kind == "parent_is_file":
        target.write_text("old")
        target = target / "child"
    before = _snapshot(box)
    expected = {"dir": IsADirectoryError, "fifo": ValueError,
                "parent_is_file": NotADirectoryError}.get(kind)
    try:
        with atomic_output(target) as tmp:
            tmp.write_text("new")
            if fail:
                raise KeyError("stop")
    except KeyError:
        assert fail and expected is None
        after = _snapshot(box)
        if kind == "missing":  # only the parent folders were made
            after = {k: v for k, v in after.items() if v[0] != stat.S_IFDIR}
        assert after == before  # a failed write changes nothing
    except (IsADirectoryError, NotADirectoryError, ValueError) as err:
        named = target.parent if kind == "parent_is_file" else target
        assert type(err) is expected and str(err).startswith(f"{named}: ")
        assert _snapshot(box) == before
    else:
        assert expected is None and not fail
        assert not target.is_symlink() and target.read_text() == "new"
        assert [p.name for p in target.parent.iterdir() if p.name.endswith(".tmp")] == []
    assert _snapshot(outside) == {"victim": (stat.S_IFREG, b"keep")}


@pytest.mark.parametrize("reader", ["image", "video"])
def test_image_and_video_readers_refuse_a_fifo_without_blocking(tmp_path, reader):
    from ferroslam.datasets.images import read_gray
    from ferroslam.sources import VideoSource

    fifo = tmp_path / ("frame.png" if reader == "image" else "clip.avi")
    os.mkfifo(fifo)
    open_it = (lambda: read_gray(fifo)) if reader == "image" else (lambda: VideoSource(fifo))
    what = "image" if reader == "image" else "video file"
    with pytest.raises(ValueError, match=f"^{fifo}: is a FIFO, expected a regular {what}"):
        open_it()
