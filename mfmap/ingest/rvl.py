"""RVL, the run-length and variable-length depth image codec of Wilson, "Fast Lossless Depth
Image Compression" (ISS 2017), as image_transport's compressedDepth plug-in writes it.

The stream alternates a count of zero pixels, a count of non-zero pixels and that many
zigzag-coded differences from the previous non-zero pixel. Every number is written in 3-bit
groups, least significant first, each group a nibble whose high bit says another follows; the
nibbles fill little-endian 32-bit words from their most significant end.
"""

from __future__ import annotations

import struct
from typing import Any

import numpy as np

from mfmap.errors import DecodeError
from mfmap.types import I64, U16

# compressed_depth_image_transport writes the image's width and height (uint32) ahead of RVL.
_SIZE = struct.Struct("<II")


def _numbers(payload: bytes) -> I64:
    """The stream's variable-length numbers, in order (padding nibbles give trailing zeros)."""
    usable = len(payload) - len(payload) % 4
    words = np.frombuffer(payload[:usable], dtype="<u4").astype(np.int64)
    shifts = np.arange(28, -4, -4, dtype=np.int64)
    nibbles = ((words[:, None] >> shifts[None, :]) & 0xF).reshape(-1)
    ends = np.flatnonzero((nibbles & 0x8) == 0)
    if ends.shape[0] == 0:
        return np.zeros(0, dtype=np.int64)
    nibbles = nibbles[: ends[-1] + 1]
    starts = np.concatenate(([0], ends[:-1] + 1))
    group = np.repeat(np.arange(ends.shape[0]), ends - starts + 1)
    place = np.arange(nibbles.shape[0]) - starts[group]
    if place.max() > 10:
        raise ValueError("a number longer than 32 bits")
    values = np.zeros(ends.shape[0], dtype=np.int64)
    np.add.at(values, group, (nibbles & 0x7) << (3 * place))
    return values


def rvl_decode(payload: bytes, n_pixels: int) -> U16:
    """n_pixels 16-bit values from an RVL stream (ValueError if the stream is short or corrupt)."""
    numbers = _numbers(payload)
    out = np.zeros(n_pixels, dtype=np.uint16)
    delta_at: list[np.ndarray[Any, Any]] = []
    pixel_at: list[np.ndarray[Any, Any]] = []
    i = pixel = 0
    while pixel < n_pixels:
        if i + 2 > numbers.shape[0]:
            raise ValueError(f"the stream ends after {pixel} of {n_pixels} pixels")
        zeros, nonzeros = int(numbers[i]), int(numbers[i + 1])
        pixel += zeros
        if pixel + nonzeros > n_pixels or i + 2 + nonzeros > numbers.shape[0]:
            raise ValueError(f"a run of {nonzeros} pixels at pixel {pixel} overruns the image "
                             f"of {n_pixels} or the stream")
        delta_at.append(np.arange(i + 2, i + 2 + nonzeros))
        pixel_at.append(np.arange(pixel, pixel + nonzeros))
        pixel += nonzeros
        i += 2 + nonzeros
    if delta_at:
        zigzag = numbers[np.concatenate(delta_at)]
        delta = (zigzag >> 1) ^ -(zigzag & 1)
        # Each value is the previous non-zero one plus its delta, in 16-bit arithmetic.
        out[np.concatenate(pixel_at)] = (np.cumsum(delta) & 0xFFFF).astype(np.uint16)
    return out


def decode_rvl_image(data: bytes, where: str) -> U16:
    """compressedDepth's RVL payload (width, height, then the stream) as a (height, width)
    uint16 image; DecodeError naming `where` if it is malformed."""
    if len(data) < _SIZE.size:
        raise DecodeError(f"{where}: compressedDepth RVL payload of {len(data)} bytes has no image size")
    width, height = _SIZE.unpack(data[: _SIZE.size])
    stream = data[_SIZE.size:]
    # RVL's best ratio is 4 bytes of pixels per byte: a larger claim is a corrupt size.
    if width == 0 or height == 0 or width * height > 5 * max(len(stream), 1):
        raise DecodeError(f"{where}: compressedDepth RVL image claims {width} x {height} pixels "
                          f"from {len(stream)} bytes")
    try:
        pixels = rvl_decode(stream, width * height)
    except ValueError as err:
        raise DecodeError(f"{where}: compressedDepth RVL stream is corrupt: {err}") from err
    return pixels.reshape(height, width)
