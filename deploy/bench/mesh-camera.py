#!/usr/bin/env python3
"""Bounds, triangle count and a framing camera for an OBJ mesh (used by embree-compare.sh).

    mesh-camera.py MESH.obj WIDTH HEIGHT [--dir X,Y,Z] [--up X,Y,Z] [--fov DEG] [--fill F]
                  [--coverage C]

Prints shell-friendly lines:

    TRIANGLES 69666
    BOUNDS minx,miny,minz maxx,maxy,maxz
    EYE x,y,z
    TARGET x,y,z
    UP x,y,z
    FOV deg

Triangles are counted as a fan per face (n-2 for an n-gon), which is how both Tessera's loader
(tobj, triangulate) and Embree's OBJ loader split polygons. Bounds are over the vertices used by
faces. The camera looks at the middle of the mesh from direction --dir (default: front right, a
little above, y up), from the closest distance at which the fraction --coverage (default 0.999)
of the vertices projects inside the fraction --fill (default 0.92) of the image width and height;
the 0.1 % left out keeps a few far vertices (the knot's floor) from shrinking the bulk of the
mesh to a corner of the picture.
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
    ap.add_argument("--coverage", type=float, default=0.999,
                    help="fraction of vertices that must be in the picture")
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
    pts = [p for i, p in enumerate(positions) if i < len(used) and used[i]]
    lo = [min(p[k] for p in pts) for k in range(3)]
    hi = [max(p[k] for p in pts) for k in range(3)]
    # Frame the bulk of the mesh: the centre is the middle of the per-axis range left after
    # dropping the (1 - coverage) / 2 most extreme vertices on each side, and the distance lets
    # the fraction `coverage` of vertices project inside the image. With coverage 1 this frames
    # every vertex; below 1 it ignores a few far-flung ones (the knot's 1,024 floor corners).
    n = len(pts)
    cut = min(n - 1, int(n * (1.0 - args.coverage) / 2))
    centre = []
    for k in range(3):
        axis = sorted(p[k] for p in pts)
        centre.append((axis[cut] + axis[n - 1 - cut]) / 2)
    tan_h = math.tan(math.radians(args.fov) / 2)
    tan_w = tan_h * args.width / args.height
    d = norm(args.dir)
    forward = [-c for c in d]
    right = norm(cross(forward, args.up))
    up = cross(right, forward)
    # Eye distance at which vertex p (relative to the centre) projects inside the fraction --fill
    # of the image: its depth D - p.d must be at least |p.right| / (fill tan_w) and
    # |p.up| / (fill tan_h).
    fw, fh = args.fill * tan_w, args.fill * tan_h
    needs = []
    for p in pts:
        q = (p[0] - centre[0], p[1] - centre[1], p[2] - centre[2])
        needs.append(dot(q, d) + max(abs(dot(q, right)) / fw, abs(dot(q, up)) / fh))
    needs.sort()
    radius = max(1e-6, math.sqrt(sum((y - x) ** 2 for x, y in zip(lo, hi))) / 2)
    distance = max(radius * 1e-3, needs[min(n - 1, max(0, math.ceil(args.coverage * n) - 1))])
    eye = [c + distance * k for c, k in zip(centre, d)]
    print(f"TRIANGLES {triangles}")
    print(f"BOUNDS {fmt(lo)} {fmt(hi)}")
    print(f"EYE {fmt(eye)}")
    print(f"TARGET {fmt(centre)}")
    print(f"UP {fmt(args.up)}")
    print(f"FOV {args.fov:g}")


if __name__ == "__main__":
    main()
