"""The real sample shipped in the package, for ``ferroslam demo`` and quick experiments.

``sample/tum_fr1_rpy.tar.bz2`` holds 90 consecutive RGB-D frames (3 s at 30 Hz, frames
210-299) of TUM fr1/rpy with their ground truth, in the standard TUM layout (CC BY 4.0,
cite Sturm et al., IROS 2012; see the README inside the archive). Built by
``scripts/make_sample.py``.

Example::

    from ferroslam.demo import sample_sequence
    from ferroslam.pipeline import run_sequence

    with sample_sequence() as seq:
        result = run_sequence(seq)
    print(result.summary()["metrics"]["ate_frames"]["rmse"])
"""

from __future__ import annotations

import tempfile
from contextlib import contextmanager
from pathlib import Path
from typing import Iterator, Union

from .archives import extract_archive
from .datasets import TumSequence

__all__ = ["DEMO_CONFIGS", "SAMPLE_ARCHIVE", "SAMPLE_NAME", "extract_sample", "sample_sequence"]

SAMPLE_ARCHIVE = Path(__file__).resolve().parent / "sample" / "tum_fr1_rpy.tar.bz2"
SAMPLE_NAME = "rgbd_dataset_freiburg1_rpy"  # folder inside the archive (names the camera)
# Per-sensor options for the sample: ORB-SLAM's TUM monocular settings use more features.
DEMO_CONFIGS: dict[str, dict] = {"rgbd": {}, "mono": {"n_features": 1500}}


def extract_sample(dest: Union[str, Path]) -> Path:
    """Extract the sample into folder ``dest``; return the sequence folder inside it.

    Raises:
        FileNotFoundError: the archive is missing from the installation (broken install).
    """
    if not SAMPLE_ARCHIVE.is_file():
        raise FileNotFoundError(
            f"the bundled sample is missing: {SAMPLE_ARCHIVE} (reinstall ferroslam; in a "
            "source checkout run `python scripts/make_sample.py`)"
        )
    extract_archive(SAMPLE_ARCHIVE, dest)
    return Path(dest) / SAMPLE_NAME


@contextmanager
def sample_sequence(*, with_depth: bool = True) -> Iterator[TumSequence]:
    """The sample as a :class:`TumSequence`, extracted to a temporary folder that is
    deleted when the ``with`` block ends (about 60 MB while it exists)."""
    with tempfile.TemporaryDirectory(prefix="ferroslam-sample-") as tmp:
        yield TumSequence(extract_sample(tmp), with_depth=with_depth)
