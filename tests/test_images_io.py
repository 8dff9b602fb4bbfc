"""Photos (facegeom.io.images): RGB pixels turned as viewers show them, every pixel format made RGB,
decompression bombs refused from the header, bad files in one line, the photos of a folder."""
from __future__ import annotations

import struct
import threading
import time
import zlib

import numpy as np
import pytest
from PIL import Image

from facegeom.errors import InputError
from facegeom.io.images import IMAGE_SUFFIXES, MAX_IMAGE_PIXELS, image_size, list_images, read_image


def picture(w: int = 64, h: int = 48) -> np.ndarray:
    """A picture whose every pixel differs from its mirror images: any turn or flip shows."""
    y, x = np.mgrid[0:h, 0:w]
    return np.stack([x * 255 // (w - 1), y * 255 // (h - 1), (x * 7 + y * 3) % 256], axis=2).astype(np.uint8)


def one_line_naming(exc: InputError, path) -> str:
    text = str(exc)
    assert len(text.splitlines()) == 1 and str(path) in text, text
    return text


def test_an_rgb_png_reads_exactly(tmp_path):
    a = picture()
    Image.fromarray(a).save(tmp_path / "p.png")
    got = read_image(tmp_path / "p.png")
    assert got.dtype == np.uint8 and got.shape == (48, 64, 3) and got.flags.writeable and got.flags.c_contiguous
    assert np.array_equal(got, a)


# what each EXIF orientation means (EXIF 2.32, tag 0x0112: where the stored 0th row and 0th column are shown),
# written out as array operations on the stored picture rather than taken from Pillow
SHOWN = {
    1: lambda a: a,
    2: lambda a: a[:, ::-1],                      # mirrored left-right
    3: lambda a: a[::-1, ::-1],                   # turned 180 degrees
    4: lambda a: a[::-1, :],                      # mirrored top-bottom
    5: lambda a: a.transpose(1, 0, 2),            # 0th row shown as the left column, 0th column as the top
    6: lambda a: np.rot90(a, k=-1),               # turned 90 degrees clockwise: a phone held upright
    7: lambda a: a[::-1, ::-1].transpose(1, 0, 2),  # 0th row shown as the right column, 0th column as the bottom
    8: lambda a: np.rot90(a, k=1),                # turned 90 degrees counter-clockwise
}


@pytest.mark.parametrize("orientation", sorted(SHOWN))
def test_the_exif_orientation_is_applied(tmp_path, orientation):
    a = picture()
    exif = Image.Exif()
    exif[0x0112] = orientation
    Image.fromarray(a).save(tmp_path / "p.png", exif=exif)  # lossless, so the pixels compare exactly
    got = read_image(tmp_path / "p.png")
    assert np.array_equal(got, SHOWN[orientation](a))
    assert image_size(tmp_path / "p.png") == (got.shape[1], got.shape[0])


def test_a_phone_portrait_jpeg_comes_out_portrait(tmp_path):
    a = picture()
    exif = Image.Exif()
    exif[0x0112] = 6
    Image.fromarray(a).save(tmp_path / "IMG_0001.JPG", exif=exif, quality=95)
    got = read_image(tmp_path / "IMG_0001.JPG")
    assert got.shape == (64, 48, 3)
    assert np.abs(got.astype(int) - np.rot90(a, k=-1).astype(int)).mean() < 4


def test_every_pixel_format_becomes_rgb_uint8(tmp_path):
    a = picture()
    gray = a[..., 0]
    cases = {}
    Image.fromarray(gray).save(tmp_path / "l.png")
    cases["l.png"] = np.repeat(gray[..., None], 3, axis=2)
    Image.fromarray(gray > 127).save(tmp_path / "bits.png")
    cases["bits.png"] = np.repeat(np.where(gray > 127, 255, 0).astype(np.uint8)[..., None], 3, axis=2)
    Image.fromarray(a).quantize(16).save(tmp_path / "palette.png")
    cases["palette.png"] = np.array(Image.fromarray(a).quantize(16).convert("RGB"))
    sixteen = gray.astype(np.uint16) * 257 + 100  # a 16-bit grayscale PNG (mode I;16): the high byte
    Image.fromarray(sixteen).save(tmp_path / "g16.png")
    cases["g16.png"] = np.repeat((sixteen >> 8).astype(np.uint8)[..., None], 3, axis=2)
    rgba = np.dstack([a, np.where(np.arange(64) < 32, 255, 0)[None, :].repeat(48, 0).astype(np.uint8)])
    Image.fromarray(rgba, "RGBA").save(tmp_path / "alpha.png")
    cases["alpha.png"] = np.where(np.arange(64)[None, :, None] < 32, a, 255).astype(np.uint8)  # over white
    la = np.dstack([gray, np.full_like(gray, 0)])
    Image.fromarray(la, "LA").save(tmp_path / "la.png")
    cases["la.png"] = np.full((48, 64, 3), 255, np.uint8)  # fully transparent: white
    Image.fromarray((gray / 255.0).astype(np.float32), "F").save(tmp_path / "float.tif")
    cases["float.tif"] = np.repeat(gray[..., None], 3, axis=2)
    for name, expected in cases.items():
        got = read_image(tmp_path / name)
        assert got.dtype == np.uint8 and got.shape == (48, 64, 3), name
        assert np.abs(got.astype(int) - expected.astype(int)).max() <= 1, name
    Image.fromarray(a).convert("CMYK").save(tmp_path / "print.jpg")
    got = read_image(tmp_path / "print.jpg")
    assert got.shape == (48, 64, 3) and np.abs(got.astype(int) - a.astype(int)).mean() < 12
    Image.fromarray(a).quantize(4).save(tmp_path / "anim.gif", save_all=True,
                                        append_images=[Image.new("P", (64, 48))])
    assert read_image(tmp_path / "anim.gif").shape == (48, 64, 3)  # the first frame


def bomb_png(path, w: int, h: int) -> None:
    """A valid RGB PNG of ``w x h`` black pixels, small on disk: each row compressed once, its bytes repeated
    (a full flush makes each row's deflate block independent), the checksum computed, not run."""
    row = bytes(1 + 3 * w)  # filter byte 0, then black
    c = zlib.compressobj(9)
    first = c.compress(row) + c.flush(zlib.Z_FULL_FLUSH)
    again = c.compress(row) + c.flush(zlib.Z_FULL_FLUSH)
    end = c.flush()[:-4]  # the last, empty block; its Adler-32 covers two rows only
    adler = ((h * len(row)) % 65521) << 16 | 1  # of n zero bytes: A = 1, B = n (RFC 1950)
    idat = first + again * (h - 1) + end + struct.pack(">I", adler)

    def chunk(kind: bytes, data: bytes) -> bytes:
        return struct.pack(">I", len(data)) + kind + data + struct.pack(">I", zlib.crc32(kind + data))

    path.write_bytes(b"\x89PNG\r\n\x1a\n" + chunk(b"IHDR", struct.pack(">IIBBBBB", w, h, 8, 2, 0, 0, 0))
                     + chunk(b"IDAT", idat) + chunk(b"IEND", b""))


def test_a_decompression_bomb_is_refused_from_its_header(tmp_path):
    small = tmp_path / "small.png"
    bomb_png(small, 300, 200)  # the construction makes a real PNG
    assert np.array_equal(read_image(small), np.zeros((200, 300, 3), np.uint8))
    bomb = tmp_path / "bomb.png"
    bomb_png(bomb, 20_000, 20_000)  # 1.2 GB once decoded
    assert bomb.stat().st_size < 2_000_000
    guard = Image.MAX_IMAGE_PIXELS
    start = time.perf_counter()
    with pytest.raises(InputError, match=r"20000 x 20000 pixels \(400.0 megapixels\), over the limit of 67.1 "
                                         "megapixels: refused before decoding") as e:
        read_image(bomb)
    assert time.perf_counter() - start < 0.5  # decoding would take seconds
    one_line_naming(e.value, bomb)
    start = time.perf_counter()
    assert image_size(bomb) == (20_000, 20_000)  # the header alone is fine
    assert time.perf_counter() - start < 0.5  # no pixel decoded (Pillow's PNG getexif would decode them all)
    assert Image.MAX_IMAGE_PIXELS == guard  # Pillow's guard is back for whoever decodes pixels
    assert MAX_IMAGE_PIXELS == 1 << 26
    with pytest.raises(InputError, match=r"300 x 200 pixels \(0.1 megapixels\), over the limit of 0.0"):
        read_image(small, max_pixels=1000)
    assert read_image(small, max_pixels=60_000).shape == (200, 300, 3)


def test_facegeoms_limit_applies_not_pillows_and_pillows_is_put_back(tmp_path, monkeypatch):
    Image.fromarray(picture()).save(tmp_path / "p.png")
    monkeypatch.setattr(Image, "MAX_IMAGE_PIXELS", 100)  # Pillow would refuse 64 x 48 as a bomb
    assert read_image(tmp_path / "p.png").shape == (48, 64, 3)
    assert Image.MAX_IMAGE_PIXELS == 100
    errors = []

    def read_many():
        try:
            for _ in range(20):
                read_image(tmp_path / "p.png")
                image_size(tmp_path / "p.png")
        except Exception as exc:  # noqa: BLE001 - reported below
            errors.append(exc)

    threads = [threading.Thread(target=read_many) for _ in range(6)]
    for t in threads:
        t.start()
    for t in threads:
        t.join()
    assert not errors and Image.MAX_IMAGE_PIXELS == 100  # no interleaving left the guard off


def test_bad_files_are_one_line_naming_the_file(tmp_path):
    a = picture(160, 120)
    Image.fromarray(a).save(tmp_path / "full.png")
    Image.fromarray(a).save(tmp_path / "full.jpg", quality=90)
    cases = {}
    for name in ("full.png", "full.jpg"):
        cut = tmp_path / f"cut_{name}"
        data = (tmp_path / name).read_bytes()
        cut.write_bytes(data[:len(data) // 2])
        cases[cut.name] = "truncated or corrupt"
    data = bytearray((tmp_path / "full.png").read_bytes())
    at = data.find(b"IDAT") + 40
    data[at:at + 30] = bytes(30)  # damaged compressed data (and a wrong CRC)
    (tmp_path / "damaged.png").write_bytes(bytes(data))
    cases["damaged.png"] = "truncated or corrupt"
    (tmp_path / "notes.jpg").write_text("not an image\n")
    cases["notes.jpg"] = r"cannot read as an image \(UnidentifiedImageError\)"
    (tmp_path / "noise.png").write_bytes(np.random.default_rng(0).integers(0, 256, 999, dtype=np.uint8).tobytes())
    cases["noise.png"] = "cannot read as an image"
    (tmp_path / "empty.png").write_bytes(b"")
    cases["empty.png"] = "empty file"
    cases["missing.png"] = "file not found"
    (tmp_path / "folder.png").mkdir()
    cases["folder.png"] = "is a folder"
    for name, message in cases.items():
        with pytest.raises(InputError, match=message) as e:
            read_image(tmp_path / name)
        one_line_naming(e.value, tmp_path / name)


def test_list_images_takes_the_photos_sorted_by_name(tmp_path):
    for name in ("img10.png", "img2.png", "b.JPG", "a.jpeg", "c.webp", "d.tif", ".hidden.jpg", "._IMG_0001.JPG"):
        (tmp_path / name).write_bytes(b"x")
    (tmp_path / "notes.txt").write_text("x")
    (tmp_path / "sub.png").mkdir()
    (tmp_path / "sub.png" / "inner.png").write_bytes(b"x")
    assert [p.name for p in list_images(tmp_path)] == ["a.jpeg", "b.JPG", "c.webp", "d.tif", "img2.png",
                                                       "img10.png"]
    assert ".png" in IMAGE_SUFFIXES and ".jpg" in IMAGE_SUFFIXES


def test_list_images_refuses_in_one_line(tmp_path):
    (tmp_path / "empty").mkdir()
    (tmp_path / "empty" / "notes.txt").write_text("x")
    (tmp_path / "file.png").write_bytes(b"x")
    for path, message in ((tmp_path / "empty", "no image in the folder"), (tmp_path / "missing", "folder not found"),
                          (tmp_path / "file.png", "is a file, not a folder")):
        with pytest.raises(InputError, match=message) as e:
            list_images(path)
        one_line_naming(e.value, path)


def test_image_size_is_the_one_fitfiles_exports():
    from facegeom.io import fitfiles

    assert fitfiles.image_size is image_size and "image_size" in fitfiles.__all__


def test_the_lens_comes_from_exif_when_the_photo_states_it(tmp_path):
    from facegeom.io.images import focal_35mm
    from facegeom.model.inputs import photo_camera

    a = picture(400, 300)
    exif = Image.Exif()
    exif.get_ifd(0x8769)[0xA405] = 26  # a phone's main camera: 26 mm equivalent
    Image.fromarray(a).save(tmp_path / "phone.jpg", exif=exif, quality=90)
    Image.fromarray(a).save(tmp_path / "plain.jpg", quality=90)
    assert focal_35mm(tmp_path / "phone.jpg") == 26.0 and focal_35mm(tmp_path / "plain.jpg") is None
    f, cx, cy, assumed = photo_camera(None, None, None, tmp_path / "phone.jpg")
    assert f == pytest.approx(26.0 * 500.0 / 43.27) and (cx, cy) == (199.5, 149.5) and not assumed
    f, _, _, assumed = photo_camera(None, None, None, tmp_path / "plain.jpg")
    assert f == 400.0 and assumed
    assert photo_camera(800.0, None, None, tmp_path / "phone.jpg")[0] == 800.0  # a given focal length is kept
    bad = Image.Exif()
    bad.get_ifd(0x8769)[0xA405] = 0  # "unknown" in EXIF
    Image.fromarray(a).save(tmp_path / "zero.jpg", exif=bad)
    assert focal_35mm(tmp_path / "zero.jpg") is None
    assert focal_35mm(tmp_path / "missing.jpg") is None
