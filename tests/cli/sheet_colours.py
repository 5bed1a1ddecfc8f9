"""Shared by the soft-tissue CLI tests: decodes an 8-bit RGB PNG (non-interlaced; filters undone
per row, with only the standard library and numpy) and counts the pixels of a sheet coloured by
displacement (viridis: green or blue above red) and the skin-coloured ones (red > green > blue).
"""
import struct
import zlib

import numpy as np


def read_png(path):
    """(h, w, 3) int32 array of an 8-bit RGB PNG."""
    b = open(path, "rb").read()
    assert b[:8] == b"\x89PNG\r\n\x1a\n", path
    pos, idat, w, h = 8, b"", 0, 0
    while pos < len(b):
        n, kind = struct.unpack(">I4s", b[pos:pos + 8])
        body = b[pos + 8:pos + 8 + n]
        if kind == b"IHDR":
            w, h, depth, ctype, _, _, interlace = struct.unpack(">IIBBBBB", body)
            assert depth == 8 and ctype == 2 and interlace == 0, (depth, ctype, interlace)
        elif kind == b"IDAT":
            idat += body
        pos += 12 + n
    raw = zlib.decompress(idat)
    stride = 3 * w
    rows, prev = [], bytearray(stride)
    for y in range(h):
        f = raw[y * (stride + 1)]
        out = bytearray(raw[y * (stride + 1) + 1:(y + 1) * (stride + 1)])
        if f == 1:
            for x in range(3, stride):
                out[x] = (out[x] + out[x - 3]) & 255
        elif f == 2:
            for x in range(stride):
                out[x] = (out[x] + prev[x]) & 255
        elif f == 3:
            for x in range(stride):
                out[x] = (out[x] + ((out[x - 3] if x >= 3 else 0) + prev[x]) // 2) & 255
        elif f == 4:
            for x in range(stride):
                a, up, c = (out[x - 3], prev[x], prev[x - 3]) if x >= 3 else (0, prev[x], 0)
                pa, pb, pc = abs(up - c), abs(a - c), abs(a + up - 2 * c)
                out[x] = (out[x] + (a if pa <= pb and pa <= pc else (up if pb <= pc else c))) & 255
        rows.append(bytes(out))
        prev = out
    return np.frombuffer(b"".join(rows), np.uint8).astype(np.int32).reshape(h, w, 3)


def count_sheet_pixels(path):
    """(rgb, displacement-coloured pixels, skin-coloured pixels) of a sheet.png. Skin (and the
    grey floor, the white background) never has blue or green above red; the viridis map below
    yellow always has."""
    rgb = read_png(path)
    r, g, bl = rgb[..., 0], rgb[..., 1], rgb[..., 2]
    coloured = int(((bl > r + 8) | (g > r + 8)).sum())
    skin = int(((r > g + 10) & (g > bl + 10) & (r < 250)).sum())
    return rgb, coloured, skin
