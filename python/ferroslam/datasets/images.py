"""Image file loading with clear errors (shared by every dataset loader)."""

from __future__ import annotations

from pathlib import Path

import cv2
import numpy as np

from .._files import regular_file

__all__ = ["IMAGE_EXTENSIONS", "read_depth", "read_gray", "read_gray_and_color"]

IMAGE_EXTENSIONS = (".png", ".jpg", ".jpeg")


def _read(path: Path) -> np.ndarray:
    """The bytes of an image file."""
    if path.suffix.lower() not in IMAGE_EXTENSIONS:
        raise ValueError(f"unsupported image type {path.suffix!r} (use .png or .jpg): {path}")
    regular_file(path, "image")  # a FIFO or device is refused before it could block
    # np.fromfile + imdecode also handles non-ASCII paths, unlike cv2.imread.
    data = np.fromfile(path, dtype=np.uint8)
    if data.size == 0:
        raise ValueError(f"empty image file: {path}")
    return data


def _decode(data: np.ndarray, flags: int, path: Path) -> np.ndarray:
    image = cv2.imdecode(data, flags)
    if image is None or image.size == 0:
        raise ValueError(f"unreadable image file (corrupt or not an image): {path}")
    return image


def _eight_bit(image: np.ndarray, path: Path) -> np.ndarray:
    if image.dtype != np.uint8:
        raise ValueError(f"expected an 8-bit image, got {image.dtype}: {path}")
    return image


def read_gray(path: str | Path) -> np.ndarray:
    """8-bit grayscale image ``(H, W)`` uint8 from a .png/.jpg file."""
    path = Path(path)
    return _eight_bit(_decode(_read(path), cv2.IMREAD_GRAYSCALE, path), path)


def read_gray_and_color(path: str | Path) -> tuple[np.ndarray, np.ndarray]:
    """``(grey (H, W), BGR (H, W, 3))`` uint8 of a .png/.jpg file, read once and decoded
    twice: the grey image is :func:`read_gray`'s, bit for bit. (Converting the colour image
    instead differs for JPEG files, whose grey decoding is the stored luma rather than a
    conversion of the upsampled colours: on few pixels, but enough to change the tracking.)"""
    path = Path(path)
    data = _read(path)
    gray = _eight_bit(_decode(data, cv2.IMREAD_GRAYSCALE, path), path)
    return gray, _eight_bit(_decode(data, cv2.IMREAD_COLOR, path), path)


def read_depth(path: str | Path, depth_factor: float) -> np.ndarray:
    """Depth map ``(H, W)`` float32 in metres from a 16-bit single-channel image.

    ``metres = pixel / depth_factor``; 0 (no measurement) stays 0.
    """
    path = Path(path)
    image = _decode(_read(path), cv2.IMREAD_UNCHANGED, path)
    if image.ndim != 2 or image.dtype != np.uint16:
        raise ValueError(
            f"depth image must be single-channel 16-bit, got {image.dtype} {image.shape}: {path}"
        )
    return image.astype(np.float32) / np.float32(depth_factor)
