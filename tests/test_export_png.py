"""``scenarios.export.png``: the EuRoC export's PNG encoder, read back by two decoders nobody
here wrote (OpenCV's libpng and Pillow's own), pixel for pixel."""

from __future__ import annotations

import io

import cv2
import numpy as np
import pytest
from PIL import Image

from scenarios.export.png import FILTER_NONE, FILTER_SUB, encode_png


def _images(dtype, channels, rng):
    """Random images, a smooth ramp (the SUB filter's good case) and the extremes, in sizes
    down to one pixel and odd widths."""
    info = np.iinfo(dtype)
    for height, width in ((1, 1), (2, 7), (13, 31), (48, 64)):
        shape = (height, width) if channels == 1 else (height, width, channels)
        yield rng.integers(0, int(info.max) + 1, shape, dtype=dtype)
        ramp = (np.arange(height * width * channels) * 37 % (int(info.max) + 1)).astype(dtype)
        yield ramp.reshape(shape)
        yield np.full(shape, info.max, dtype=dtype)


@pytest.mark.parametrize("row_filter", [FILTER_NONE, FILTER_SUB])
@pytest.mark.parametrize(("dtype", "channels"), [(np.uint8, 3), (np.uint8, 1), (np.uint16, 1)])
def test_a_png_decodes_to_the_same_pixels(dtype, channels, row_filter):
    """OpenCV (libpng, which checks every chunk's CRC) and Pillow read each file back equal
    to the image, colour in R, G, B order, 16-bit samples whole."""
    rng = np.random.default_rng(7)
    for image in _images(dtype, channels, rng):
        data = encode_png(image, row_filter)
        decoded = cv2.imdecode(np.frombuffer(data, np.uint8), cv2.IMREAD_UNCHANGED)
        assert decoded is not None and decoded.dtype == image.dtype
        if channels == 3:
            decoded = cv2.cvtColor(decoded, cv2.COLOR_BGR2RGB)
        np.testing.assert_array_equal(decoded, image)
        with Image.open(io.BytesIO(data)) as pil:
            pil.load()  # inflates the whole stream: a truncated or corrupt one raises
            assert pil.size == (image.shape[1], image.shape[0])
            np.testing.assert_array_equal(np.asarray(pil).astype(image.dtype), image)


def test_a_non_contiguous_image_is_encoded_as_its_pixels():
    """A view (every other column, a flipped colour order) is encoded as the pixels it shows."""
    rgb = np.random.default_rng(1).integers(0, 256, (9, 20, 3), dtype=np.uint8)
    view = rgb[:, ::2, ::-1]
    decoded = cv2.imdecode(np.frombuffer(encode_png(view), np.uint8), cv2.IMREAD_UNCHANGED)
    np.testing.assert_array_equal(decoded, view[..., ::-1])


def test_the_sub_filter_makes_a_smooth_depth_smaller():
    """A smooth 16-bit depth (a tilted plane) with the SUB filter is smaller than unfiltered:
    the filter is applied, not only declared (the decoding tests hold either way)."""
    v, u = np.mgrid[0:120, 0:160]
    depth_mm = (2000 + 7 * v + 3 * u).astype(np.uint16)
    assert len(encode_png(depth_mm, FILTER_SUB)) < len(encode_png(depth_mm, FILTER_NONE)) / 2


@pytest.mark.parametrize(
    ("image", "row_filter", "match"),
    [
        (np.zeros((4, 4), np.float32), FILTER_NONE, "uint8 or uint16"),
        (np.zeros((4, 4, 4), np.uint8), FILTER_NONE, r"\(H, W, 3\)"),
        (np.zeros((4,), np.uint8), FILTER_NONE, "uint8 or uint16"),
        (np.zeros((0, 4), np.uint8), FILTER_NONE, "at least one pixel"),
        (np.zeros((4, 4), np.uint8), 4, "row_filter"),
    ],
)
def test_an_image_it_cannot_encode_is_a_value_error(image, row_filter, match):
    with pytest.raises(ValueError, match=match):
        encode_png(image, row_filter)
