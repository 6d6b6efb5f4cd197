"""Where the shared real-data fixtures live (TUM, KITTI, EuRoC excerpts, evo references).

``FERROSLAM_DATA`` wins; otherwise ``<repo>/../shared/data`` (the layout of the development
machines and of CI). The folder is read-only and never copied into the repository.
"""

from __future__ import annotations

import os
from pathlib import Path

__all__ = ["data_dir"]

_REPO = Path(__file__).resolve().parents[2]


def data_dir() -> Path:
    """Path of the shared data folder (it may not exist: callers decide how to react)."""
    env = os.environ.get("FERROSLAM_DATA")
    if env:
        return Path(env).expanduser()
    return (_REPO.parent / "shared" / "data").resolve()
