#!/usr/bin/env python3
"""Writes a large synthetic u8 volume as raw voxels with a Tessera sidecar, for out-of-core runs.

  make-big-volume.py NX NY NZ OUT_DIR          writes OUT_DIR/big.raw and OUT_DIR/big.vol.toml
  make-big-volume.py NX NY NZ OUT_DIR STEPS    a time series instead: OUT_DIR/tNNN.raw and
                                               tNNN.vol.toml per step, the blobs drifting, and
                                               OUT_DIR/series.scene.toml naming them

The field is three rounded blobs in a rippled box: the saturating sum of a profile along each
axis, so a whole row is one `bytes.translate` of a precomputed row and 1024 x 1024 x 512 voxels
(512 MiB here; 2 GiB as the f32 samples a renderer holds) take about a minute with nothing but
Python. Prints the sidecar's path (the scene file's, for a series).
"""
import math
import os
import sys


def profile(n, bumps):
    """Per index along an axis: the largest of `bumps` (centre, width, height) there."""
    out = []
    for i in range(n):
        t = i / max(n - 1, 1)
        out.append(max(h * math.exp(-((t - c) / w) ** 2) for c, w, h in bumps))
    return out


def write_step(nx, ny, nz, out, name, drift):
    """Writes OUT/NAME.raw and NAME.vol.toml, the blobs moved by `drift` (a share of the box)."""
    fx = profile(nx, [(0.3 + drift, 0.2, 110), (0.7 - drift, 0.15, 100)])
    ripple = [8 * math.sin(i / 9.0 + drift * 20) for i in range(nx)]
    fy = profile(ny, [(0.5 + drift / 2, 0.25, 90)])
    fz = profile(nz, [(0.45, 0.3, 80)])
    row = bytes(max(0, min(255, int(fx[x] + ripple[x] + 40))) for x in range(nx))
    # One table per offset: value v becomes the saturating v + offset - 120.
    tables = [bytes(max(0, min(255, v + d - 120)) for v in range(256)) for d in range(256)]
    raw = os.path.join(out, name + ".raw")
    with open(raw, "wb") as f:
        for z in range(nz):
            slab = bytearray()
            for y in range(ny):
                d = max(0, min(255, int(fy[y] + fz[z])))
                slab += row.translate(tables[d])
            f.write(slab)
            if z % 64 == 0:
                print(f"make-big-volume: {name}, slice {z} of {nz}", file=sys.stderr)
    sidecar = os.path.join(out, name + ".vol.toml")
    with open(sidecar, "w") as f:
        f.write(f'data = "{name}.raw"\ndims = [{nx}, {ny}, {nz}]\ntype = "u8"\nspacing = [1.0, 1.0, 1.0]\n')
    return sidecar


def main():
    if len(sys.argv) not in (5, 6):
        sys.exit(__doc__)
    nx, ny, nz = (int(a) for a in sys.argv[1:4])
    out = sys.argv[4]
    os.makedirs(out, exist_ok=True)
    if len(sys.argv) == 5:
        print(write_step(nx, ny, nz, out, "big", 0.0))
        return
    steps = int(sys.argv[5])
    if steps < 1:
        sys.exit(f"make-big-volume: STEPS {steps} is not a positive count")
    for s in range(steps):
        write_step(nx, ny, nz, out, f"t{s:03}", 0.1 * math.sin(2 * math.pi * s / steps))
    scene = os.path.join(out, "series.scene.toml")
    with open(scene, "w") as f:
        f.write('series = "t*.vol.toml"\n')
    print(scene)


main()
