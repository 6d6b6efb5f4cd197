"""ORB vocabulary and keyframe database for place recognition (native: ``ferroslam._core``).

``default_vocabulary()`` loads the vocabulary shipped in the package (``orb_vocabulary.fsv``,
k = 10, L = 5; provenance in ``README.md`` beside it). Custom vocabularies: train one with
``Vocabulary.train`` on ``extract_descriptors(image_paths(...))`` (what ``ferroslam vocab
train`` does), or read ORB-SLAM's ``ORBvoc.txt`` with ``Vocabulary.load_dbow2_text``.
"""

from __future__ import annotations

from functools import lru_cache
from pathlib import Path
from typing import Iterable, Union

import numpy as np

from .._core import KeyframeDatabase, Vocabulary
from .._files import atomic_output

__all__ = [
    "DEFAULT_VOCABULARY_PATH",
    "KeyframeDatabase",
    "Vocabulary",
    "default_vocabulary",
    "extract_descriptors",
    "image_paths",
    "save_vocabulary",
]

DEFAULT_VOCABULARY_PATH = Path(__file__).resolve().parent / "orb_vocabulary.fsv"
"""The shipped vocabulary file (ferroslam binary format)."""

_IMAGE_SUFFIXES = {".png", ".jpg", ".jpeg", ".pgm", ".bmp"}


@lru_cache(maxsize=1)
def default_vocabulary() -> Vocabulary:
    """The shipped vocabulary, read once per process (a ``Vocabulary`` is immutable).

    Raises:
        FileNotFoundError: the file is missing from the installation.
        ValueError: the file is corrupt.
    """
    return Vocabulary.load(DEFAULT_VOCABULARY_PATH)


def image_paths(paths: Iterable[Union[str, Path]], step: int = 1) -> list[Path]:
    """Image files named directly, plus every ``step``-th image of each folder (sorted by name).

    Raises:
        FileNotFoundError: a path does not exist.
        ValueError: ``step < 1``, or no image at all.
    """
    if step < 1:
        raise ValueError(f"step must be >= 1, got {step}")
    out: list[Path] = []
    for p in map(Path, paths):
        if p.is_dir():
            files = sorted(f for f in p.iterdir() if f.suffix.lower() in _IMAGE_SUFFIXES)
            out.extend(files[::step])
        elif p.is_file():
            out.append(p)
        else:
            raise FileNotFoundError(f"no such image or folder: {p}")
    if not out:
        raise ValueError(f"no images found in {[str(p) for p in map(Path, paths)]}")
    return out


def extract_descriptors(images: Iterable[Union[str, Path]], n_features: int = 1000,
                        ) -> list[np.ndarray]:
    """ORB descriptors ``(N, 32)`` uint8 of each image (``features.OrbExtractor``), in order.

    Raises:
        ValueError: an image cannot be read.
    """
    from ..datasets.images import read_gray
    from ..features import OrbExtractor

    extractor = OrbExtractor(n_features=n_features)
    return [np.ascontiguousarray(extractor.detect(read_gray(Path(p)))[1], dtype=np.uint8)
            .reshape(-1, 32) for p in images]


def save_vocabulary(vocabulary: Vocabulary, path: Union[str, Path], *,
                    dbow2_text: bool = False) -> Path:
    """Writes ``vocabulary`` to ``path`` (ferroslam binary, or DBoW2 text as ORB-SLAM's
    ``ORBvoc.txt`` with ``dbow2_text``) through :func:`ferroslam._files.atomic_output`: the
    file appears complete or not at all, a symlink there is replaced, a FIFO or device is
    refused (``ValueError``), a folder too (``IsADirectoryError``)."""
    path = Path(path)
    with atomic_output(path) as tmp:
        if dbow2_text:
            vocabulary.save_dbow2_text(tmp)
        else:
            vocabulary.save(tmp)
    return path
