"""Image payload codecs: every encoding round-trips; damage raises DecodeError."""
import struct

import cv2
import numpy as np
import pytest

from planar_vo.io import codecs as c


@pytest.fixture(scope="module")
def images():
    rng = np.random.default_rng(1)
    bgr = rng.integers(0, 256, (30, 40, 3), dtype=np.uint8)
    mm = rng.integers(0, 65536, (30, 40)).astype(np.uint16)
    return bgr, mm


@pytest.mark.parametrize("enc", ["png", "bgr8", "rgb8"])
def test_lossless_color_roundtrip(images, enc):
    bgr, _ = images
    e = c.encode_color(bgr, enc)
    out = c.decode_raw_color(e.encoding, 30, 40, e.step, e.data) if e.raw else c.decode_compressed_color(e.data)
    np.testing.assert_array_equal(out, bgr)
    assert out.flags.writeable and out.dtype == np.uint8


def test_mono8_gives_grey_bgr(images):
    bgr, _ = images
    e = c.encode_color(bgr, "mono8")
    out = c.decode_raw_color("mono8", 30, 40, e.step, e.data)
    grey = cv2.cvtColor(bgr, cv2.COLOR_BGR2GRAY)
    assert out.shape == (30, 40, 3)
    for ch in range(3):
        np.testing.assert_array_equal(out[..., ch], grey)


def test_jpeg_close_to_original():
    yy, xx = np.mgrid[0:48, 0:64]
    smooth = np.stack([(xx * 3 + yy * ch) % 256 for ch in (1, 2, 3)], -1).astype(np.uint8)
    e = c.encode_color(smooth, "jpeg", jpeg_quality=95)
    assert e.format == "bgr8; jpeg compressed bgr8" and e.data[:2] == b"\xff\xd8"
    out = c.decode_compressed_color(e.data)
    assert np.abs(out.astype(int) - smooth).mean() < 3.0


@pytest.mark.parametrize("enc", ["png", "jpeg", "bgr8", "rgb8", "bgra8", "mono8"])
def test_gray_decode_is_the_intensity_of_the_colour_decode(images, enc):
    """``gray=True`` (what the pipeline reads) gives (H, W) uint8: the BGR decode converted
    to grey, exactly for raw payloads, to libpng's rounding (1 level) for PNG; a JPEG's
    luma plane, read directly, differs only where the colour decode clipped a pixel
    (on the renders and the demo: mean 0.001 level, one pixel in 10^4 beyond 1)."""
    bgr, _ = images
    if enc == "jpeg":  # a smooth image: JPEG's own loss is not under test here
        yy, xx = np.mgrid[0:30, 0:40]
        bgr = np.stack([(xx * 3 + yy * ch) % 256 for ch in (1, 2, 3)], -1).astype(np.uint8)
    if enc == "bgra8":
        data = np.dstack([bgr, np.full(bgr.shape[:2], 255, np.uint8)]).tobytes()
        colour, out = (c.decode_raw_color("bgra8", 30, 40, 160, data, gray=g) for g in (False, True))
    else:
        e = c.encode_color(bgr, enc)
        decode = ((lambda g: c.decode_raw_color(e.encoding, 30, 40, e.step, e.data, gray=g)) if e.raw
                  else (lambda g: c.decode_compressed_color(e.data, gray=g)))
        colour, out = decode(False), decode(True)
    assert out.shape == (30, 40) and out.dtype == np.uint8 and out.flags.writeable
    diff = np.abs(out.astype(int) - cv2.cvtColor(colour, cv2.COLOR_BGR2GRAY))
    if enc == "jpeg":
        assert diff.mean() < 0.1 and np.mean(diff <= 1) > 0.99
    else:
        assert diff.max() <= (1 if enc == "png" else 0)


def test_raw_rows_with_padding_and_big_endian():
    rng = np.random.default_rng(2)
    mm = rng.integers(0, 65536, (5, 7)).astype(">u2")
    padded = np.zeros((5, 20), np.uint8)
    padded[:, :14] = mm.view(np.uint8).reshape(5, 14)
    out = c.decode_raw_depth("16UC1", 5, 7, 20, padded.tobytes(), is_bigendian=True)
    np.testing.assert_array_equal(out, mm.astype(np.float32) / np.float32(1000))


@pytest.mark.parametrize("enc", ["png", "compressedDepth", "16UC1"])
def test_millimetre_depth_roundtrip(images, enc):
    _, mm = images
    depth = mm.astype(np.float32) / np.float32(1000)
    e = c.encode_depth(depth, enc)
    out = c.decode_raw_depth(e.encoding, 30, 40, e.step, e.data) if e.raw else \
        c.decode_compressed_depth(e.format, e.data)
    np.testing.assert_array_equal(out, depth)


def test_compressed_depth_header_layout(images):
    _, mm = images
    e = c.encode_depth(mm.astype(np.float32) / 1000, "compressedDepth")
    fmt, a, b = struct.unpack_from("<iff", e.data)
    assert (fmt, a, b) == (1, 0.0, 0.0) and e.data[12:20] == b"\x89PNG\r\n\x1a\n"
    assert e.format == "16UC1; compressedDepth png"


def test_32fc1_exact_and_invalid_values_become_zero():
    d = np.array([[1.2345678, np.nan, np.inf], [-1.0, 0.0, 7.5]], np.float32)
    e = c.encode_depth(d, "32FC1")
    out = c.decode_raw_depth("32FC1", 2, 3, e.step, e.data)
    np.testing.assert_array_equal(out, [[np.float32(1.2345678), 0, 0], [0, 0, 7.5]])


def test_compressed_depth_32fc1_inverse_depth():
    # compressed_depth_image_transport: q = A / d + B with B = A / max_depth; q = 0 invalid.
    A, max_depth = 100.0, 10.0
    B = A / max_depth
    d = np.array([[0.5, 1.0, 2.0, 0.0]], np.float32)
    q = np.where(d > 0, np.rint(A / np.where(d > 0, d, 1) + B), 0).astype(np.uint16)
    ok, png = cv2.imencode(".png", q)
    data = struct.pack("<iff", 0, A, B) + png.tobytes()
    out = c.decode_compressed_depth("32FC1; compressedDepth", data)
    np.testing.assert_allclose(out, d, atol=1e-6)


def test_depth_to_mm_clips_out_of_range():
    d = np.array([0.0005, 65.535, 65.6, -3.0, np.nan], np.float32)
    np.testing.assert_array_equal(c.depth_to_mm(d), [0, 65535, 0, 0, 0])


@pytest.mark.parametrize("call", [
    lambda: c.decode_compressed_color(b"not an image"),
    lambda: c.decode_compressed_depth("16UC1; png compressed", b"\x00" * 40),
    lambda: c.decode_raw_color("bgr8", 10, 10, 30, b"\x00" * 299),
    lambda: c.decode_raw_depth("16UC1", 10, 10, 10, b"\x00" * 200),  # step < row bytes
    lambda: c.decode_compressed_depth("16UC1; compressedDepth", b"\x00" * 5),
])
def test_damaged_payloads_raise_decode_error(call):
    with pytest.raises(c.DecodeError):
        call()


def test_colour_png_for_depth_is_rejected():
    ok, png = cv2.imencode(".png", np.zeros((4, 4, 3), np.uint8))
    with pytest.raises(c.DecodeError, match="16-bit"):
        c.decode_compressed_depth("png", png.tobytes())


def test_unsupported_encodings_are_input_errors():
    with pytest.raises(c.UnsupportedEncoding, match="yuv422"):
        c.decode_raw_color("yuv422", 2, 2, 4, b"\x00" * 8)
    with pytest.raises(c.UnsupportedEncoding, match="RVL"):
        c.decode_compressed_depth("16UC1; compressedDepth rvl", b"\x02\x00\x00\x00" + b"\x00" * 20)
