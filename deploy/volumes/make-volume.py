#!/usr/bin/env python3
"""Writes a synthetic volume as NRRD (raw f32, or u8/i16), for trying and testing volume scenes.

  make-volume.py ml N OUT.nrrd       Marschner-Lobb test signal on N^3 (values 0..1)
  make-volume.py blobs N OUT.nrrd    three overlapping Gaussian blobs (values 0..1)
  make-volume.py ct N OUT.nrrd       a CT-like phantom in Hounsfield units (i16): air, a soft
                                     tissue ellipsoid (about 40 HU), a bone shell (about 700 HU)

Pure Python (no numpy), so it runs anywhere; N up to about 128 takes seconds.
"""
import math
import struct
import sys


def marschner_lobb(x, y, z):
    # x, y, z in -1..1; the classic fM = 6, alpha = 0.25.
    r = math.sqrt(x * x + y * y)
    rho = math.cos(2 * math.pi * 6 * math.cos(math.pi * r / 2))
    return (1 - math.sin(math.pi * z / 2) + 0.25 * (1 + rho)) / (2 * (1 + 0.25))


def blobs(x, y, z):
    centres = [(-0.3, -0.2, 0.0, 0.35), (0.35, 0.1, 0.1, 0.3), (0.0, 0.35, -0.25, 0.25)]
    return min(1.0, sum(math.exp(-((x - cx) ** 2 + (y - cy) ** 2 + (z - cz) ** 2) / (s * s))
                        for cx, cy, cz, s in centres))


def ct(x, y, z):
    e = (x / 0.8) ** 2 + (y / 0.65) ** 2 + (z / 0.9) ** 2
    if e > 1.0:
        return -1000.0
    shell = abs(math.sqrt(e) - 0.8)
    return 40.0 + (660.0 if shell < 0.06 else 0.0)


def main():
    if len(sys.argv) != 4 or sys.argv[1] not in ("ml", "blobs", "ct"):
        sys.exit(__doc__)
    kind, n, out = sys.argv[1], int(sys.argv[2]), sys.argv[3]
    if not 2 <= n <= 512:
        sys.exit("N must be from 2 to 512")
    field = {"ml": marschner_lobb, "blobs": blobs, "ct": ct}[kind]
    fmt, nrrd_type = ("<h", "short") if kind == "ct" else ("<f", "float")
    coord = [-1 + 2 * i / (n - 1) for i in range(n)]
    data = bytearray()
    for z in coord:
        for y in coord:
            for x in coord:
                v = field(x, y, z)
                data += struct.pack(fmt, int(round(v)) if kind == "ct" else v)
    spacing = 2.0 / (n - 1)
    header = (
        "NRRD0004\n"
        f"type: {nrrd_type}\n"
        "dimension: 3\n"
        f"sizes: {n} {n} {n}\n"
        f"spacings: {spacing} {spacing} {spacing}\n"
        "endian: little\n"
        "encoding: raw\n"
        "\n"
    )
    with open(out, "wb") as f:
        f.write(header.encode())
        f.write(data)
    print(f"{out}: {kind} {n}^3, {len(data)} bytes of {nrrd_type}")


if __name__ == "__main__":
    main()
