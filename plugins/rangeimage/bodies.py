"""The entropy stage (``body=``): a general-purpose coder, or an image codec for layer 0.

- ``zstd`` / ``lzma``: the whole raw body (:mod:`.layers`) through zstandard or the standard
  library's LZMA2 (raw format, a fixed 8 MiB dictionary -- the decoder sets it, never the
  bytes). LZMA2's range coder with literal contexts takes 10-20 % off zstd level 3 on these
  byte planes (measured in ``docs/codecs.md``), for a slower encode.
- ``png`` (16-bit grey, zlib), ``jpegxl`` (lossless), ``jpegxl-lossy``, ``zfp`` (fixed
  accuracy, float32 metres) through ``imagecodecs``: the layer-0 range image -- every cell, the
  empty ones filled with their row's previous value so the codec's predictors see a smooth
  image -- as one image; everything else (mask, offsets, overflow, exceptions) through zstd.

Decoding is bounded before a library sees the bytes: zstd by :func:`lwbench.zstd_decompress`,
LZMA2 by ``max_length``; for the images the header is parsed here first and must declare exactly
the grid's shape and sample type (PNG: the IHDR chunk; JPEG XL: the codestream's SizeHeader --
imagecodecs allocates whatever a header declares, and decodes *every* frame unless told one; ZFP:
no header of sizes at all, and a bit reader without bounds checks, so its mode word must be the
one this encoder writes and the stream is padded with zeros for the bits one block may read).
"""

from __future__ import annotations

import lzma
import struct

import numpy as np

from lwbench import ParameterError, PayloadError, zstd_decompress

__all__ = ["BODIES", "IMAGE_BODIES", "LEVELS", "compress", "decode_image", "decompress", "encode_image"]

IMAGE_BODIES = ("png", "jpegxl", "jpegxl-lossy", "zfp")
BODIES = ("zstd", "lzma", *IMAGE_BODIES)
#: Allowed ``level`` per body and its default (zstd level, LZMA preset, zlib level, JPEG XL effort).
LEVELS = {"zstd": (1, 22, 3), "lzma": (0, 9, 6), "png": (1, 9, 6), "jpegxl": (1, 9, 7), "jpegxl-lossy": (1, 9, 7),
          "zfp": (1, 1, 1)}
_LZMA_DICT = 1 << 23
_PNG_SIGNATURE = b"\x89PNG\r\n\x1a\n"
_JXL_SIGNATURE = b"\xff\x0a"
_JXL_CONTAINER = b"\x00\x00\x00\x0cJXL \r\n\x87\n"
_JXL_MAX_BOXES = 16
_JXL_RATIOS = ((1, 1), (12, 10), (4, 3), (3, 2), (16, 9), (5, 4), (2, 1))
# zfp: the most bits one 2-D float block may take (ZFP_MAX_BITS in zfp 1.0), rounded up.
_ZFP_BLOCK_BYTES = 2088


def level_for(body: str, level: int | None) -> int:
    lo, hi, default = LEVELS[body]
    if level is None:
        return default
    if not lo <= level <= hi:
        raise ParameterError(f"rangeimage: level for body={body} is {lo}..{hi}, got {level}")
    return level


def _lzma_filters(preset: int | None = None) -> list[dict]:
    """LZMA2 with a fixed dictionary; the encoder adds its preset with ``pb=0`` (no 4-byte
    alignment: the planes are byte streams) and ``nice_len=128`` -- together 1 % smaller than
    the plain preset on the shared real scans at the same speed (``docs/codecs.md``)."""
    f: dict = {"id": lzma.FILTER_LZMA2, "dict_size": _LZMA_DICT}
    if preset is not None:
        f.update(preset=preset, pb=0, nice_len=128)
    return [f]


def compress(raw: bytes, body: str, level: int | None) -> bytes:
    """The side stream: zstd, or LZMA2 when ``body`` is ``lzma``."""
    if body == "lzma":
        return lzma.compress(raw, format=lzma.FORMAT_RAW, filters=_lzma_filters(level_for("lzma", level)))
    import zstandard

    return zstandard.ZstdCompressor(level=level_for("zstd", level) if body == "zstd" else 3).compress(raw)


def decompress(data: bytes, body: str, size: int) -> bytes:
    """Inverse of :func:`compress`, exactly ``size`` bytes or ``PayloadError``."""
    what = "rangeimage payload"
    if body != "lzma":
        return zstd_decompress(data, size, what, exact=True)
    d = lzma.LZMADecompressor(format=lzma.FORMAT_RAW, filters=_lzma_filters())
    try:
        out = d.decompress(data, max_length=size + 1)
    except lzma.LZMAError as exc:
        raise PayloadError(f"{what}: LZMA2 stream is corrupt ({exc})") from None
    if len(out) != size or not d.eof or d.unused_data:
        got = f"{len(out)}{'' if d.eof else '+'}"
        raise PayloadError(f"{what}: LZMA2 stream inflates to {got} bytes, expected {size}")
    return out


# -- images ----------------------------------------------------------------------------------
def encode_image(image: np.ndarray, body: str, level: int | None, *, tolerance: float = 0.0,
                 distance: float = 1.0) -> bytes:
    """Layer 0 as an image: uint16 steps (png, jpegxl*) or float32 metres (zfp)."""
    import imagecodecs

    if body == "png":
        return bytes(imagecodecs.png_encode(np.ascontiguousarray(image, np.uint16), level=level_for(body, level)))
    if body in ("jpegxl", "jpegxl-lossy"):
        lossless = body == "jpegxl"
        return bytes(imagecodecs.jpegxl_encode(
            np.ascontiguousarray(image, np.uint16), effort=level_for(body, level), lossless=lossless,
            distance=None if lossless else distance, numthreads=1,
        ))
    return bytes(imagecodecs.zfp_encode(np.ascontiguousarray(image, np.float32), tolerance, mode="accuracy",
                                        header=False, numthreads=1))


def _png_header(blob: bytes) -> tuple[int, int, int, int, int]:
    """(height, width, bit depth, colour type, interlace) from the IHDR chunk, which comes first."""
    if len(blob) < 33 or blob[:8] != _PNG_SIGNATURE or blob[8:16] != b"\x00\x00\x00\x0dIHDR":
        raise PayloadError("rangeimage payload: the PNG image has no IHDR chunk first")
    width, height, depth, colour, _, _, interlace = struct.unpack(">IIBBBBB", blob[16:29])
    return height, width, depth, colour, interlace


class _Bits:
    """LSB-first bit reader (JPEG XL's order)."""

    def __init__(self, data: bytes) -> None:
        self.value, self.pos = int.from_bytes(data, "little"), 0

    def take(self, n: int) -> int:
        v = (self.value >> self.pos) & ((1 << n) - 1)
        self.pos += n
        return v


def _jxl_u32(bits: _Bits) -> int:
    return bits.take((9, 13, 18, 30)[bits.take(2)]) + 1


def _jxl_codestream(blob: bytes) -> bytes:
    """The start of the codestream: the blob itself, or the first ``jxlc`` / ``jxlp`` box of a
    container (ISO/IEC 18181-2; libjxl writes one for 16-bit samples, with a ``jxll`` level box)."""
    if blob[:2] == _JXL_SIGNATURE:
        return blob
    if blob[:12] != _JXL_CONTAINER:
        raise PayloadError("rangeimage payload: the JPEG XL image has neither signature")
    pos = 0
    for _ in range(_JXL_MAX_BOXES):
        if pos + 8 > len(blob):
            break
        size, kind = struct.unpack(">I4s", blob[pos:pos + 8])
        head = 8
        if size == 1:
            if pos + 16 > len(blob):
                break
            size, head = struct.unpack(">Q", blob[pos + 8:pos + 16])[0], 16
        elif size == 0:
            size = len(blob) - pos
        if kind in (b"jxlc", b"jxlp"):
            start = pos + head + (4 if kind == b"jxlp" else 0)  # jxlp: a 4-byte sequence index first
            return blob[start:pos + size] if size >= head else b""
        if size < head:
            break
        pos += size
    raise PayloadError("rangeimage payload: the JPEG XL container holds no codestream box")


def _jxl_shape(blob: bytes) -> tuple[int, int]:
    """(ysize, xsize) from the JPEG XL codestream's SizeHeader (ISO/IEC 18181-1)."""
    code = _jxl_codestream(blob)
    if code[:2] != _JXL_SIGNATURE or len(code) < 3:
        raise PayloadError("rangeimage payload: the JPEG XL codestream has no signature")
    bits = _Bits(code[2:20])
    small = bits.take(1)
    ysize = (bits.take(5) + 1) * 8 if small else _jxl_u32(bits)
    ratio = bits.take(3)
    if ratio:
        num, den = _JXL_RATIOS[ratio - 1]
        return ysize, ysize * num // den
    return ysize, (bits.take(5) + 1) * 8 if small else _jxl_u32(bits)


def _zfp_header(tolerance: float) -> tuple[bytes, int]:
    """What this encoder writes before a ZFP stream of the given tolerance: the bytes and bits."""
    import imagecodecs

    probe = bytes(imagecodecs.zfp_encode(np.zeros((4, 4), np.float32), tolerance, mode="accuracy", header=False))
    mode = (int.from_bytes(probe[:16], "little") >> 32) & 0xFFF
    nbits = 32 + (12 if mode < 0xFFF else 64)
    return probe, nbits


def _same_bits(a: bytes, b: bytes, nbits: int) -> bool:
    n = (nbits + 7) // 8
    if len(a) < n or len(b) < n:
        return False
    mask = (1 << nbits) - 1
    return int.from_bytes(a[:n], "little") & mask == int.from_bytes(b[:n], "little") & mask


def decode_image(blob: bytes, body: str, shape: tuple[int, int], *, tolerance: float = 0.0) -> np.ndarray:
    """Inverse of :func:`encode_image`: an image of exactly ``shape`` or ``PayloadError``."""
    import imagecodecs

    if body == "png":
        if _png_header(blob) != (*shape, 16, 0, 0):
            raise PayloadError(f"rangeimage payload: the PNG image is not a {shape[1]}x{shape[0]} 16-bit grey image")
        decode = lambda: imagecodecs.png_decode(blob, out=np.empty(shape, np.uint16))  # noqa: E731
    elif body in ("jpegxl", "jpegxl-lossy"):
        if _jxl_shape(blob) != shape:
            raise PayloadError(f"rangeimage payload: the JPEG XL image is not {shape[1]}x{shape[0]}")
        decode = lambda: imagecodecs.jpegxl_decode(blob, index=0, numthreads=1,  # noqa: E731
                                                   out=np.empty(shape, np.uint16))
    else:
        header, nbits = _zfp_header(tolerance)
        if not _same_bits(blob, header, nbits):
            raise PayloadError("rangeimage payload: the ZFP stream's mode is not the one its tolerance gives")
        blocks = ((shape[0] + 3) // 4) * ((shape[1] + 3) // 4)
        padded = blob + bytes(_ZFP_BLOCK_BYTES + blocks // 8 + 64)
        decode = lambda: imagecodecs.zfp_decode(padded, shape=shape, dtype=np.float32,  # noqa: E731
                                                out=np.empty(shape, np.float32))
    try:
        image = np.asarray(decode())
    except Exception as exc:  # noqa: BLE001 - any failure of the library on these bytes
        why = f"{type(exc).__name__}: {exc}"
        raise PayloadError(f"rangeimage payload: the {body} image does not decode ({why})") from None
    if image.shape != shape:
        raise PayloadError(f"rangeimage payload: the {body} image decodes to {image.shape}, expected {shape}")
    return image
