"""Python API of the vocabulary (``ferroslam.vocabulary``, ``_core.Vocabulary`` and
``_core.KeyframeDatabase``): round trips, the shipped file, the CLI, and bad input."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from ferroslam import cli

vocabulary = pytest.importorskip("ferroslam.vocabulary")
Vocabulary = vocabulary.Vocabulary
KeyframeDatabase = vocabulary.KeyframeDatabase


def _images(n: int, rows: int = 200, seed: int = 0) -> list[np.ndarray]:
    rng = np.random.default_rng(seed)
    return [rng.integers(0, 256, (rows, 32), dtype=np.uint8) for _ in range(n)]


@pytest.fixture(scope="module")
def small() -> Vocabulary:
    return Vocabulary.train(_images(4), k=4, levels=3, seed=1)


def test_train_is_deterministic_and_shaped(small, tmp_path):
    again = Vocabulary.train(_images(4), k=4, levels=3, seed=1)
    small.save(tmp_path / "a.fsv")
    again.save(tmp_path / "b.fsv")
    assert (tmp_path / "a.fsv").read_bytes() == (tmp_path / "b.fsv").read_bytes()
    assert (small.k, small.levels) == (4, 3)
    assert 4 < small.num_words <= 4**3
    assert repr(small) == f"Vocabulary(k=4, levels=3, num_words={small.num_words})"


def test_transform_and_score(small):
    images = _images(2, seed=5)
    bow = small.transform(images[0])
    assert bow and all(isinstance(w, int) and 0 <= w < small.num_words for w in bow)
    assert sum(bow.values()) == pytest.approx(1.0)
    assert small.transform(np.zeros((0, 32), np.uint8)) == {}
    assert Vocabulary.score(bow, bow) == pytest.approx(1.0)
    assert Vocabulary.score(bow, {}) == 0.0
    assert Vocabulary.score({1: 1.0}, {2: 3.0}) == 0.0
    assert Vocabulary.score({1: 1.0, 2: 3.0}, {1: 1.0, 2: 1.0}) == pytest.approx(0.75)
    # Views with any strides are accepted.
    assert small.transform(np.asfortranarray(images[0])) == bow


def test_binary_and_dbow2_text_round_trips(small, tmp_path):
    d = _images(1, seed=9)[0]
    small.save(tmp_path / "v.fsv")
    loaded = Vocabulary.load(str(tmp_path / "v.fsv"))
    assert loaded.transform(d) == small.transform(d)
    small.save_dbow2_text(tmp_path / "v.txt")
    text = Vocabulary.load_dbow2_text(tmp_path / "v.txt")
    assert (text.k, text.levels, text.num_words) == (small.k, small.levels, small.num_words)
    a, b = text.transform(d), small.transform(d)
    assert a.keys() == b.keys()
    assert Vocabulary.score(a, b) == pytest.approx(1.0, abs=1e-6)


def test_database_add_remove_query(small):
    images = _images(3, seed=2)
    db = KeyframeDatabase(small)
    assert len(db) == 0 and db.query(images[0]) == []
    assert db.add(10, images[0]) is False
    assert db.add(11, images[1]) is False
    assert db.add(11, images[1]) is True  # replaced
    assert len(db) == 2 and 10 in db and 12 not in db and -1 not in db
    results = db.query(images[0], max_results=5)
    assert results[0][0] == 10 and results[0][1] == pytest.approx(1.0)
    q = small.transform(images[0])
    for kf, score in results:
        expect = Vocabulary.score(q, small.transform(images[kf - 10]))
        assert score == pytest.approx(expect, abs=1e-12)
    assert [kf for kf, _ in db.query(images[0], 5, exclude={10})] == [11]
    assert db.query(images[0], 5, exclude=[10, 11]) == []
    assert len(db.query(images[0], max_results=1)) == 1
    assert db.remove(10) is True and db.remove(10) is False
    assert [kf for kf, _ in db.query(images[0])] == [11]
    assert repr(db) == "KeyframeDatabase(1 keyframes)"


def test_shipped_vocabulary():
    path = vocabulary.DEFAULT_VOCABULARY_PATH
    assert path.parent == Path(vocabulary.__file__).resolve().parent
    assert path.stat().st_size < 5 * 2**20
    voc = vocabulary.default_vocabulary()
    assert voc is vocabulary.default_vocabulary()  # read once
    assert (voc.k, voc.levels, voc.num_words) == (10, 5, 71083)


# --- bad input -------------------------------------------------------------------------------

@pytest.mark.parametrize("bad, error, match", [
    (np.zeros((5, 32), np.int16), TypeError, "descriptors must be a uint8 \\(N, 32\\) array, got int16"),
    (np.zeros((5, 16), np.uint8), ValueError, "descriptors must have shape \\(N, 32\\).*\\(5, 16\\)"),
    (np.zeros(32, np.uint8), TypeError, "descriptors must be"),
    ([[0] * 32], TypeError, "descriptors must be .* got list"),
])
def test_bad_descriptors(small, bad, error, match):
    with pytest.raises(error, match=match):
        small.transform(bad)
    db = KeyframeDatabase(small)
    with pytest.raises(error, match=match):
        db.add(0, bad)
    with pytest.raises(error, match=match):
        db.query(bad)


@pytest.mark.parametrize("kwargs, error, match", [
    (dict(descriptor_list=[np.zeros((3, 32), np.uint8), np.zeros((3, 31), np.uint8)]),
     ValueError, "descriptor_list\\[1\\] must have shape"),
    (dict(descriptor_list=[np.zeros((3, 32), np.float32)]), TypeError, "descriptor_list\\[0\\]"),
    (dict(descriptor_list="abc"), TypeError, "descriptor_list must be a list"),
    (dict(descriptor_list=5), TypeError, "descriptor_list must be a list"),
    (dict(descriptor_list=[]), ValueError, "no training descriptors"),
    (dict(descriptor_list=[np.zeros((0, 32), np.uint8)]), ValueError, "no training descriptors"),
    (dict(descriptor_list=[np.zeros((3, 32), np.uint8)], k=1), ValueError, "k must be"),
    (dict(descriptor_list=[np.zeros((3, 32), np.uint8)], levels=0), ValueError, "levels must be"),
    (dict(descriptor_list=[np.zeros((3, 32), np.uint8)], levels=17), ValueError, "levels must be"),
])
def test_bad_training_input(kwargs, error, match):
    with pytest.raises(error, match=match):
        Vocabulary.train(**kwargs)


def test_bad_scores_and_database_arguments(small):
    with pytest.raises(TypeError, match="a must be a dict"):
        Vocabulary.score([1.0], {})
    with pytest.raises(ValueError, match="b: weight of word 3 is -1"):
        Vocabulary.score({}, {3: -1.0})
    with pytest.raises(ValueError, match="weight of word 3 is NaN"):
        Vocabulary.score({3: float("nan")}, {})
    with pytest.raises(ValueError, match="a: word id must be in 0"):
        Vocabulary.score({-3: 1.0}, {})
    with pytest.raises(TypeError, match="vocabulary must be a ferroslam Vocabulary"):
        KeyframeDatabase("voc.fsv")
    db = KeyframeDatabase(small)
    d = _images(1)[0]
    with pytest.raises(ValueError, match="id must be in 0..=4294967295, got -1"):
        db.add(-1, d)
    with pytest.raises(ValueError, match="id must be"):
        db.remove(2**32)
    with pytest.raises(ValueError, match="max_results must be"):
        db.query(d, -1)
    with pytest.raises(TypeError, match="exclude must be an iterable of int ids"):
        db.query(d, exclude=3)
    with pytest.raises(TypeError, match="exclude must be"):
        db.query(d, exclude=["a"])


def test_missing_and_corrupt_files_name_the_file(tmp_path):
    missing = tmp_path / "missing.fsv"
    with pytest.raises(FileNotFoundError, match="missing.fsv"):
        Vocabulary.load(missing)
    with pytest.raises(FileNotFoundError, match="missing.fsv"):
        Vocabulary.load_dbow2_text(missing)
    good = vocabulary.DEFAULT_VOCABULARY_PATH.read_bytes()
    flipped = bytearray(good)
    flipped[len(good) // 2] ^= 0x10
    cases = {
        "garbage.fsv": b"not a vocabulary" * 10,
        "truncated.fsv": good[: len(good) // 3],
        "flipped.fsv": bytes(flipped),
        "empty.fsv": b"",
    }
    for name, data in cases.items():
        (tmp_path / name).write_bytes(data)
        with pytest.raises(ValueError, match=name):
            Vocabulary.load(tmp_path / name)
    (tmp_path / "bad.txt").write_text("10 5 0 0\n0 0 1 2 3\n")
    with pytest.raises(ValueError, match="bad.txt"):
        Vocabulary.load_dbow2_text(tmp_path / "bad.txt")
    (tmp_path / "a_file").write_text("")
    with pytest.raises(OSError, match="cannot create folder .*a_file"):
        vocabulary.default_vocabulary().save(tmp_path / "a_file" / "v.fsv")


def test_image_paths_errors(tmp_path):
    with pytest.raises(FileNotFoundError, match="nothing_here"):
        vocabulary.image_paths([tmp_path / "nothing_here"])
    with pytest.raises(ValueError, match="no images found"):
        vocabulary.image_paths([tmp_path])
    with pytest.raises(ValueError, match="step must be"):
        vocabulary.image_paths([tmp_path], step=0)


# --- CLI -------------------------------------------------------------------------------------

def test_vocab_cli_arguments():
    args = cli.build_parser().parse_args(["vocab", "train", "a", "b", "--out", "v.fsv"])
    assert (args.command, args.vocab_command, args.images) == ("vocab", "train", [Path("a"), Path("b")])
    assert (args.k, args.levels, args.seed, args.step, args.features) == (10, 5, 0, 1, 1000)
    assert args.text is None
    args = cli.build_parser().parse_args(["vocab", "export-dbow2", "o.txt"])
    assert (args.out, args.vocabulary) == (Path("o.txt"), None)
    with pytest.raises(SystemExit):
        cli.build_parser().parse_args(["vocab", "train", "a"])  # --out is required


def test_vocab_cli_train_and_export(tmp_path, capsys):
    rng = np.random.default_rng(3)
    import cv2

    folder = tmp_path / "images"
    folder.mkdir()
    for i in range(3):  # textured images so FAST finds corners
        noise = rng.integers(0, 256, (60, 80), dtype=np.uint8)
        image = cv2.resize(noise, (320, 240), interpolation=cv2.INTER_NEAREST)
        cv2.imwrite(str(folder / f"{i:03d}.png"), image)
    out, text = tmp_path / "v.fsv", tmp_path / "v.txt"
    assert cli.main(["vocab", "train", str(folder), "--k", "4", "--levels", "3",
                     "--features", "300", "--out", str(out), "--text", str(text)]) == 0
    assert "descriptors from 3 images" in capsys.readouterr().out
    voc = Vocabulary.load(out)
    assert (voc.k, voc.levels) == (4, 3)
    assert Vocabulary.load_dbow2_text(text).num_words == voc.num_words
    exported = tmp_path / "e.txt"
    assert cli.main(["vocab", "export-dbow2", str(exported), "--vocabulary", str(out)]) == 0
    assert exported.read_bytes() == text.read_bytes()
    assert cli.main(["vocab", "train", str(tmp_path / "none"), "--out", str(out)]) == 1
    assert "no such image or folder" in capsys.readouterr().err
