#!/usr/bin/env python3
"""Runs two tessera-render-node binaries' `bench` alternately on the same meshes, so that a
busy machine slows both alike, and prints each figure's median for each and their ratio.

    alternate.py OLD NEW --mesh A.ply --mesh B.obj [--threads 1,2] [--rounds 3] [--frames 5]

OLD and NEW are binaries (e.g. one built from main before a change, one after). Each round
runs OLD then NEW (then NEW then OLD the next round) for every mesh and thread count; every
run is `bench --scene MESH --threads N --frames F --no-scaling --ao 16 --ao-unbounded`.
A figure one binary does not print shows as a dash. Binaries before 2026-12-04 print no
`TESSERA_AO_SURFACE_MRAYPS`: their `TESSERA_AO_MRAYPS` traced those rays (from t = 0, not
Embree's 0.001), so it is read as their `ao-surface`, and their `ao` shows as a dash.
"""
import argparse
import os
import re
import statistics
import subprocess
import sys

FIGURES = [
    ("TESSERA_PRIMARY_MRAYPS", "primary"),
    ("TESSERA_EYELIGHT_MRAYPS", "eyelight"),
    ("TESSERA_FULL_MRAYPS", "full"),
    ("TESSERA_SHADOW_SINGLE_MRAYPS", "shadow1"),
    ("TESSERA_AO_MRAYPS", "ao"),
    ("TESSERA_AO_SURFACE_MRAYPS", "ao-surface"),
    ("TESSERA_BYTES_PER_TRIANGLE", "B/tri"),
]


def bench(binary, mesh, threads, frames):
    cmd = [binary, "bench", "--scene", mesh, "--threads", str(threads), "--frames",
           str(frames), "--no-scaling", "--ao", "16", "--ao-unbounded"]
    run = subprocess.run(cmd, capture_output=True, text=True, timeout=900)
    if run.returncode != 0:
        sys.exit(f"alternate: {' '.join(cmd)} failed ({run.returncode}):\n{run.stderr[-2000:]}")
    found = {}
    for key, name in FIGURES:
        m = re.search(rf"^{key} ([0-9.]+)", run.stdout, re.M)
        if m:
            found[name] = float(m.group(1))
    if "ao-surface" not in found and "ao" in found:
        found["ao-surface"] = found.pop("ao")
    return found


def main():
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("old")
    p.add_argument("new")
    p.add_argument("--mesh", action="append", required=True)
    p.add_argument("--threads", default="1,2")
    p.add_argument("--rounds", type=int, default=3)
    p.add_argument("--frames", type=int, default=5)
    a = p.parse_args()
    for b in (a.old, a.new):
        if not os.access(b, os.X_OK):
            sys.exit(f"alternate: {b} is not an executable")
    print(f"load average at start: {os.getloadavg()[0]:.2f}")
    names = [n for _, n in FIGURES]
    print(f"{'mesh':<22}{'thr':>4}  " + "  ".join(f"{n:>22}" for n in names))
    print(f"{'':<26}  " + "  ".join(f"{'old / new / ratio':>22}" for _ in names))
    for mesh in a.mesh:
        for threads in [int(t) for t in a.threads.split(",")]:
            runs = {a.old: [], a.new: []}
            for r in range(a.rounds):
                order = (a.old, a.new) if r % 2 == 0 else (a.new, a.old)
                for b in order:
                    runs[b].append(bench(b, mesh, threads, a.frames))
            cells = []
            for n in names:
                olds = [x[n] for x in runs[a.old] if n in x]
                news = [x[n] for x in runs[a.new] if n in x]
                if not olds or not news:
                    cells.append("-")
                    continue
                old, new = statistics.median(olds), statistics.median(news)
                cells.append(f"{old:7.1f} {new:7.1f} {new / old:5.2f}")
            print(f"{os.path.basename(mesh):<22}{threads:>4}  " + "  ".join(f"{c:>22}" for c in cells),
                  flush=True)


if __name__ == "__main__":
    main()
