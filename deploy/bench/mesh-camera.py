#!/usr/bin/env python3
"""Bounds, triangle count and a framing camera for an OBJ mesh (used by embree-compare.sh).

    mesh-camera.py MESH.obj WIDTH HEIGHT [--dir X,Y,Z] [--up X,Y,Z] [--fov DEG] [--fill F]

Prints shell-friendly lines:

    TRIANGLES 69666
    BOUNDS minx,miny,minz maxx,maxy,maxz
    EYE x,y,z
    TARGET x,y,z
    UP x,y,z
    FOV deg

Triangles are counted as a fan per face (n-2 for an n-gon), which is how both Tessera's loader
(tobj, triangulate) and Embree's OBJ loader split polygons. Bounds are over the vertices used by
faces. The camera looks at the centre of the bounds from direction --dir (default: front right,
a little above, y up), from the closest distance at which every vertex projects inside the
fraction --fill of the image width and height.
"""
import argparse
import math
import sys


def vec(text):
    parts = [float(p) for p in text.split(",")]
    if len(parts) != 3 or not all(math.isfinite(p) for p in parts):
        raise argparse.ArgumentTypeError(f"expected X,Y,Z, got {text!r}")
    return parts


def norm(v):
    length = math.sqrt(sum(c * c for c in v))
    if length == 0.0:
        sys.exit("mesh-camera: zero-length vector")
    return [c / length for c in v]


def dot(a, b):
    return sum(x * y for x, y in zip(a, b))


def cross(a, b):
    return [a[1] * b[2] - a[2] * b[1], a[2] * b[0] - a[0] * b[2], a[0] * b[1] - a[1] * b[0]]


def fmt(v):
    return ",".join(f"{c:.6g}" for c in v)


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("mesh")
    ap.add_argument("width", type=int)
    ap.add_argument("height", type=int)
    ap.add_argument("--dir", type=vec, default=[0.55, 0.45, 0.8],
                    help="direction from the centre to the eye")
    ap.add_argument("--up", type=vec, default=[0.0, 1.0, 0.0])
    ap.add_argument("--fov", type=float, default=40.0, help="vertical field of view, degrees")
    ap.add_argument("--fill", type=float, default=0.92)
    args = ap.parse_args()
    if not args.mesh.lower().endswith(".obj"):
        sys.exit(f"mesh-camera: {args.mesh}: only .obj is read here (export other formats first)")

    positions = []
    used = None  # vertex indices used by faces (None until a face is seen)
    triangles = 0
    with open(args.mesh, "rb") as f:
        for line in f:
            if line.startswith(b"v "):
                x, y, z = line.split()[1:4]
                positions.append((float(x), float(y), float(z)))
            elif line.startswith(b"f "):
                refs = line.split()[1:]
                if len(refs) < 3:
                    continue
                triangles += len(refs) - 2
                if used is None:
                    used = bytearray()
                for r in refs:
                    i = int(r.split(b"/")[0])
                    i = i - 1 if i > 0 else len(positions) + i
                    if i >= len(used):
                        used.extend(b"\0" * (max(i + 1, 2 * len(used)) - len(used)))
                    used[i] = 1
    if triangles == 0:
        sys.exit(f"mesh-camera: {args.mesh}: no triangles")
    lo = [math.inf] * 3
    hi = [-math.inf] * 3
    for i, p in enumerate(positions):
        if i < len(used) and used[i]:
            for k in range(3):
                lo[k] = min(lo[k], p[k])
                hi[k] = max(hi[k], p[k])
    centre = [(a + b) / 2 for a, b in zip(lo, hi)]
    radius = max(1e-6, math.sqrt(sum((b - a) ** 2 for a, b in zip(lo, hi))) / 2)
    tan_h = math.tan(math.radians(args.fov) / 2)
    tan_w = tan_h * args.width / args.height
    d = norm(args.dir)
    forward = [-c for c in d]
    right = norm(cross(forward, args.up))
    up = cross(right, forward)
    # Closest eye distance at which every used vertex projects inside the fraction --fill of the
    # image: for vertex p (relative to the centre), depth = D - p.d must be at least
    # |p.right| / (fill tan_w) and |p.up| / (fill tan_h).
    fw, fh = args.fill * tan_w, args.fill * tan_h
    distance = radius * 1e-3
    for i, p in enumerate(positions):
        if i < len(used) and used[i]:
            q = [p[0] - centre[0], p[1] - centre[1], p[2] - centre[2]]
            need = dot(q, d) + max(abs(dot(q, right)) / fw, abs(dot(q, up)) / fh)
            if need > distance:
                distance = need
    eye = [c + distance * k for c, k in zip(centre, d)]
    print(f"TRIANGLES {triangles}")
    print(f"BOUNDS {fmt(lo)} {fmt(hi)}")
    print(f"EYE {fmt(eye)}")
    print(f"TARGET {fmt(centre)}")
    print(f"UP {fmt(args.up)}")
    print(f"FOV {args.fov:g}")


if __name__ == "__main__":
    main()
