"""Photos: their pixels as RGB arrays, the photos of a folder, a photo's size from its header.

- :func:`read_image`: an ``(H, W, 3)`` uint8 RGB array turned upright as
  viewers show it (the EXIF orientation applied), whatever the file's pixel
  format (grayscale, palette, transparency, 16-bit, CMYK).
- :func:`image_size`: the shown ``(width, height)`` from the header alone.
- :func:`list_images`: the photos of a folder (``facegeom detect FOLDER``).

Decompression bombs: a small file can declare a huge picture (a 1 MB PNG of
20,000 x 20,000 pixels needs 1.2 GB once decoded). :func:`read_image`
reads the size from the header and refuses a picture over ``max_pixels``
before any pixel is decoded. The default, :data:`MAX_IMAGE_PIXELS` (64 Mi
pixels, 67.1 million), holds the full-resolution photo of every camera up to
a 64-megapixel phone sensor (9248 x 6936) or a 61-megapixel full-frame body,
and keeps the memory of one photo under 1 GB (at the limit: Pillow's decoded
picture at 4 bytes a pixel, 270 MB, and the 200 MB RGB array, copied once on
the way). Phones save 12-50 megapixels unless
a "high resolution" mode is on; a 108- or 200-megapixel photo is refused with
a message saying so (scale it down, or pass a larger ``max_pixels``).

Pillow's own guard (``PIL.Image.MAX_IMAGE_PIXELS``, a warning at 89
megapixels and an error at twice that) is switched off while facegeom reads
a photo, as facegeom's limit applies instead; it is put back afterwards, also
when several threads read photos at once.
"""
from __future__ import annotations

import contextlib
import os
import re
import threading
from pathlib import Path

import numpy as np

from facegeom.errors import InputError

__all__ = ["IMAGE_SUFFIXES", "MAX_IMAGE_PIXELS", "read_image", "image_size", "list_images", "focal_35mm"]

#: The file names :func:`list_images` takes as photos (compared lower-case).
IMAGE_SUFFIXES = (".jpg", ".jpeg", ".png", ".bmp", ".tif", ".tiff", ".webp", ".ppm", ".pgm", ".pbm", ".pnm")

#: Most pixels :func:`read_image` decodes by default (64 Mi pixels; see the module notes for why).
MAX_IMAGE_PIXELS = 1 << 26

_ORIENTATION = 0x0112  # the EXIF tag
_ALPHA_MODES = ("RGBA", "LA", "PA", "RGBa", "La")
_SIXTEEN_BIT_MODES = ("I;16", "I;16L", "I;16B", "I;16N", "I")


def _check_file(path: Path, what: str) -> None:
    """Refuse a missing, folder, special (a FIFO would block) or empty ``path``."""
    if not path.exists():
        raise InputError("file not found", path)
    if path.is_dir():
        raise InputError(f"is a folder, not {what} file", path)
    if not path.is_file():
        raise InputError(f"is not a regular file (a device or a pipe), not {what} file", path)
    if path.stat().st_size == 0:
        raise InputError("empty file", path)


# Pillow's bomb guard is one global; it is off while any facegeom read is under way and put back by the last one
# to finish, so two threads cannot leave it off (one saving the other's None)
_guard_lock = threading.Lock()
_guard_users = 0
_guard_saved: int | None = None


@contextlib.contextmanager
def _pillow_guard_off():
    """Pillow's decompression-bomb guard off in the body (facegeom checks the size itself)."""
    global _guard_users, _guard_saved
    from PIL import Image

    with _guard_lock:
        if _guard_users == 0:
            _guard_saved = Image.MAX_IMAGE_PIXELS
            Image.MAX_IMAGE_PIXELS = None
        _guard_users += 1
    try:
        yield
    finally:
        with _guard_lock:
            _guard_users -= 1
            if _guard_users == 0:
                Image.MAX_IMAGE_PIXELS = _guard_saved


def _orientation(im) -> int:
    """The EXIF orientation tag of an opened image from what its header holds (1, upright, when absent or unreadable).

    Pillow's ``PngImageFile.getexif`` decodes every pixel to look for an
    ``eXIf`` chunk after the image data (PNG allows it only before); the
    general method reads what was found before the pixels, so the header
    alone is read (a PNG decompression bomb stays undecoded).
    """
    from PIL import Image

    try:
        value = Image.Image.getexif(im).get(_ORIENTATION, 1)
        return int(value) if isinstance(value, int) else 1
    except Exception:  # noqa: BLE001 - a malformed EXIF block must not make a readable photo unreadable
        return 1


def image_size(path: str | os.PathLike) -> tuple[int, int]:
    """The ``(width, height)`` in pixels of a photo as it is shown (any format Pillow reads; only its header is read).

    A photo whose EXIF orientation turns it by 90 degrees (a portrait taken
    with a phone held upright: tags 5-8) has its width and height swapped, as
    viewers show it and annotators mark it. Pillow's guard against
    decompression bombs does not apply: no pixel is decoded.

    Parameters
    ----------
    path : str or os.PathLike
        The photo.

    Returns
    -------
    (int, int)
        Width and height, both positive.

    Raises
    ------
    InputError
        Missing, empty, or not an image Pillow can read.
    """
    path = Path(path)
    _check_file(path, "an image")
    try:
        from PIL import Image

        with _pillow_guard_off(), Image.open(path) as im:  # lazy: the header only, no pixel decoded
            w, h = im.size
            turned = _orientation(im) in (5, 6, 7, 8)
    except Exception as exc:  # noqa: BLE001 - Pillow raises many types on a malformed or unknown file
        raise InputError(f"cannot read as an image ({exc.__class__.__name__})", path) from None
    if turned:
        w, h = h, w
    if not (w > 0 and h > 0):
        raise InputError(f"the image has no pixels ({w} x {h})", path)
    return int(w), int(h)


_EXIF_IFD = 0x8769
_FOCAL_35MM = 0xA405  # FocalLengthIn35mmFilm: the lens as a 35 mm film camera's (phones and most cameras write it)


def focal_35mm(path: str | os.PathLike) -> float | None:
    """The lens's 35 mm-equivalent focal length (mm) the photo's EXIF states, or None (no EXIF, no such tag, a
    value no lens has). Only the header is read.

    The focal length in pixels follows from the photo's diagonal: a 35 mm frame's diagonal is 43.27 mm, so
    ``f_px = focal_35mm * hypot(width, height) / 43.27``.
    """
    try:
        from PIL import Image

        with _pillow_guard_off(), Image.open(path) as im:
            value = Image.Image.getexif(im).get_ifd(_EXIF_IFD).get(_FOCAL_35MM)
        value = float(value)
    except Exception:  # noqa: BLE001 - a malformed EXIF block says nothing; the photo itself stays readable
        return None
    return value if 8.0 <= value <= 2000.0 else None  # 8 mm: past a fisheye; 2000 mm: past any telephoto


def _megapixels(n: int) -> str:
    return f"{n / 1e6:.1f} megapixels"


def _short(exc: BaseException) -> str:
    """``Type: message`` of an exception, the message cut to 120 characters."""
    text = " ".join(str(exc).split())
    return f"{exc.__class__.__name__}: {text[:120]}" if text else exc.__class__.__name__


def _to_rgb(im) -> np.ndarray:
    """The pixels of a loaded, upright Pillow image as ``(H, W, 3)`` uint8 RGB (a new, writable array)."""
    from PIL import Image

    mode = im.mode
    if mode in _SIXTEEN_BIT_MODES or mode == "F":
        a = np.asarray(im)
        if mode == "F":  # floating point: 0-1 if it fits there, else 0-255
            a = np.nan_to_num(a.astype(np.float64), nan=0.0, posinf=255.0, neginf=0.0)
            scale = 255.0 if a.size and a.max() <= 1.0 else 1.0
            gray = np.clip(np.rint(a * scale), 0, 255).astype(np.uint8)
        else:  # 16-bit (a 32-bit "I" image is taken as 16-bit values): the high byte
            gray = (np.clip(a, 0, 65535).astype(np.uint32) >> 8).astype(np.uint8)
        return np.repeat(gray[:, :, None], 3, axis=2)
    if mode in _ALPHA_MODES or "transparency" in im.info:
        # transparent pixels are shown over white (a viewer's page); their stored colour is often junk
        rgba = im.convert("RGBA")
        white = Image.new("RGBA", rgba.size, (255, 255, 255, 255))
        rgb = Image.alpha_composite(white, rgba).convert("RGB")
    elif mode == "RGB":
        rgb = im
    else:  # 1, L, P, CMYK, YCbCr, LAB, HSV, ...
        rgb = im.convert("RGB")
    return np.array(rgb, dtype=np.uint8)


def read_image(path: str | os.PathLike, max_pixels: int = MAX_IMAGE_PIXELS) -> np.ndarray:
    """Read a photo as RGB pixels, turned as viewers show it.

    The EXIF orientation is applied (``PIL.ImageOps.exif_transpose``): a
    portrait taken with a phone held upright comes out portrait. Grayscale,
    palette and CMYK pictures are converted to RGB; 16-bit pictures keep
    their high byte; transparent pixels are shown over white. Of an animated
    or multi-page file (GIF, TIFF, WebP) the first frame is read. Colour
    profiles (ICC) are not applied.

    Parameters
    ----------
    path : str or os.PathLike
        Any format Pillow reads (JPEG, PNG, BMP, TIFF, WebP, GIF, ...).
    max_pixels : int, optional
        Most pixels (width x height) decoded; a larger picture is refused from
        its header, before any pixel is decoded. Default
        :data:`MAX_IMAGE_PIXELS` (64 Mi pixels; see the module notes).

    Returns
    -------
    (H, W, 3) uint8
        The pixels, row 0 at the top, as shown.

    Raises
    ------
    InputError
        One line naming the file: missing, empty, a folder, not an image,
        larger than ``max_pixels`` (with its size), truncated or corrupt.
    """
    path = Path(path)
    _check_file(path, "an image")
    try:
        limit = int(max_pixels)
    except (TypeError, ValueError):
        raise InputError(f"max_pixels must be a whole number, got {max_pixels!r}", path) from None
    if limit < 1:
        raise InputError(f"max_pixels must be positive, got {limit}", path)
    from PIL import Image, ImageOps

    with _pillow_guard_off():
        try:
            im = Image.open(path)  # lazy: the header only
        except Exception as exc:  # noqa: BLE001 - Pillow raises many types on a malformed or unknown file
            raise InputError(f"cannot read as an image ({exc.__class__.__name__})", path) from None
        with im:
            w, h = im.size
            if not (w > 0 and h > 0):
                raise InputError(f"the image has no pixels ({w} x {h})", path)
            if w * h > limit:
                raise InputError(f"the image is {w} x {h} pixels ({_megapixels(w * h)}), over the limit of "
                                 f"{_megapixels(limit)}: refused before decoding (a decompression bomb, or a photo "
                                 "to scale down first)", path)
            turned = _orientation(im) != 1  # from the header, as image_size reads it
            try:
                im.load()
                upright = ImageOps.exif_transpose(im) if turned else im
                rgb = _to_rgb(upright)
            except MemoryError:
                # the size is within the limit, so a corrupt length field asked for gigabytes (Pillow reads a
                # PNG chunk's declared length at once), or memory is short
                raise InputError("cannot decode the image, corrupt or out of memory (MemoryError)", path) from None
            except Exception as exc:  # noqa: BLE001 - decoders raise OSError, SyntaxError, ValueError, ...
                raise InputError(f"cannot decode the image, truncated or corrupt ({_short(exc)})", path) from None
    if rgb.ndim != 3 or rgb.shape[2] != 3 or rgb.shape[0] * rgb.shape[1] == 0:  # pragma: no cover - Pillow's promise
        raise InputError(f"decoded to an unexpected shape {rgb.shape}", path)
    return rgb


_DIGITS = re.compile(r"([0-9]+)")


def _natural_key(path: Path) -> tuple:
    """Sort key of a file name with its digit runs compared as numbers (``img2`` before ``img10``)."""
    parts = _DIGITS.split(path.name)
    return tuple(int(p) if i % 2 else p.casefold() for i, p in enumerate(parts)), path.name


def list_images(folder: str | os.PathLike) -> list[Path]:
    """The photos of a folder, sorted by name, for processing a folder of photos.

    A file counts as a photo by its suffix (:data:`IMAGE_SUFFIXES`, any case);
    other files, subfolders and hidden files (a name starting with ``.``, such
    as the ``._IMG_0001.JPG`` companions macOS leaves on USB drives) are
    skipped. Subfolders are not searched. Names sort with their numbers
    compared as numbers, so ``frame_2.png`` comes before ``frame_10.png``.

    Parameters
    ----------
    folder : str or os.PathLike
        The folder.

    Returns
    -------
    list of Path
        At least one photo. The files are not opened: a file that is not
        really an image is refused by :func:`read_image` later.

    Raises
    ------
    InputError
        Naming the folder: missing, not a folder, unreadable, or without any photo.
    """
    folder = Path(folder)
    if not folder.exists():
        raise InputError("folder not found", folder)
    if not folder.is_dir():
        raise InputError("is a file, not a folder of images", folder)
    try:
        entries = list(folder.iterdir())
    except OSError as exc:
        raise InputError(f"cannot list the folder ({exc.strerror or exc.__class__.__name__})", folder) from None
    images = [p for p in entries
              if p.suffix.lower() in IMAGE_SUFFIXES and not p.name.startswith(".") and p.is_file()]
    if not images:
        raise InputError(f"no image in the folder (looked for {', '.join(IMAGE_SUFFIXES)})", folder)
    return sorted(images, key=_natural_key)
