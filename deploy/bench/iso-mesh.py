#!/usr/bin/env python3
"""Extracts an iso-surface of a CT volume as a binary PLY mesh with VTK's flying edges:
a scanned surface of millions of irregular triangles that nobody here modelled.

    iso-mesh.py VOLUME.nhdr ISO OUT.ply

VOLUME is a NRRD header (deploy/volumes/fetch-cranium.sh writes the CT head's); ISO is in the
data's own units (400: bone of the CT head). Prints the triangle count.
"""
import sys

import vtk


def main():
    if len(sys.argv) != 4:
        sys.exit(__doc__)
    volume, iso, out = sys.argv[1], float(sys.argv[2]), sys.argv[3]
    reader = vtk.vtkNrrdReader()
    reader.SetFileName(volume)
    reader.Update()
    if reader.GetOutput().GetNumberOfPoints() == 0:
        sys.exit(f"iso-mesh: {volume}: VTK read no voxels")
    surface = vtk.vtkFlyingEdges3D()
    surface.SetInputConnection(reader.GetOutputPort())
    surface.SetValue(0, iso)
    surface.ComputeNormalsOff()
    surface.ComputeGradientsOff()
    surface.ComputeScalarsOff()
    surface.Update()
    triangles = surface.GetOutput().GetNumberOfPolys()
    if triangles == 0:
        sys.exit(f"iso-mesh: no surface at {iso} in {volume}")
    writer = vtk.vtkPLYWriter()
    writer.SetFileName(out)
    writer.SetFileTypeToBinary()
    writer.SetInputConnection(surface.GetOutputPort())
    if writer.Write() != 1:
        sys.exit(f"iso-mesh: could not write {out}")
    print(triangles)


if __name__ == "__main__":
    main()
