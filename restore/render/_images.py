"""Writing and reading rendered images: EXR (linear, via Mitsuba), NumPy, and tonemapped PNG previews.

Every write goes to a temporary file in the destination folder and is then renamed over
the destination, so an interrupted write never leaves a truncated image behind.
"""

from __future__ import annotations

import os
from pathlib import Path

import numpy as np

from .._io import atomic_write, matplotlib_for

IMAGE_SUFFIXES = (".exr", ".npy", ".png")


def _as_image(image) -> np.ndarray:
    array = np.asarray(image, dtype=np.float32)
    if array.ndim != 3 or array.shape[2] != 3:
        raise ValueError(f"an image must have shape (height, width, 3), got {array.shape}")
    return array


def tonemap(image, exposure: float = 0.0) -> np.ndarray:
    """Linear RGB to 8-bit sRGB: scale by `2**exposure`, clip to [0, 1], apply the sRGB curve."""
    linear = np.clip(_as_image(image) * 2.0**exposure, 0.0, 1.0)
    linear = np.nan_to_num(linear, nan=0.0)
    srgb = np.where(linear <= 0.0031308, 12.92 * linear, 1.055 * np.power(linear, 1 / 2.4) - 0.055)
    return np.round(srgb * 255).astype(np.uint8)


def _save_npy(tmp: Path, array: np.ndarray) -> None:
    with open(tmp, "wb") as handle:  # a handle: np.save appends ".npy" to a name like "image.NPY"
        np.save(handle, array)


def save_image(path: str | os.PathLike, image, exposure: float = 0.0) -> Path:
    """Write `image` `(H, W, 3)` to `path`: `.exr` (linear float, needs Mitsuba), `.npy`, or `.png` (tonemapped).

    Raises:
        ValueError: for another suffix or an image of the wrong shape.
        ImportError: for `.exr` without the `mitsuba` extra (write `.npy` instead).
    """
    path = Path(path)
    suffix = path.suffix.lower()
    if suffix not in IMAGE_SUFFIXES:
        raise ValueError(f"unsupported image file {path.name!r}: use one of {', '.join(IMAGE_SUFFIXES)}")
    array = _as_image(image)
    if suffix == ".npy":
        return atomic_write(path, lambda tmp: _save_npy(tmp, array))
    if suffix == ".png":
        matplotlib_for("writing PNG images", backend=None)
        import matplotlib.image

        return atomic_write(path, lambda tmp: matplotlib.image.imsave(tmp, tonemap(array, exposure), format="png"))
    if not path.parent.is_dir():
        raise FileNotFoundError(f"cannot write {path}: folder {path.parent} does not exist")
    from targets.mitsuba import write_exr

    return write_exr(path, array)


def load_image(path: str | os.PathLike) -> np.ndarray:
    """Read an `(H, W, 3)` float32 image written by `save_image` (`.exr` or `.npy`)."""
    path = Path(path)
    if not path.is_file():
        raise FileNotFoundError(f"no image at {path}")
    suffix = path.suffix.lower()
    if suffix == ".npy":
        return _as_image(np.load(path))
    if suffix == ".exr":
        from targets.mitsuba import read_exr

        return _as_image(read_exr(path))
    raise ValueError(f"cannot read {path.name!r}: use an .exr or .npy image")
