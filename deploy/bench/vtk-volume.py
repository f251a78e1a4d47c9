#!/usr/bin/env python3
"""One volume rendered by VTK's CPU ray caster (vtkFixedPointVolumeRayCastMapper), as Tessera
renders it: the same raw volume (a Tessera .vol.toml sidecar), transfer function (a Tessera
transfer TOML in data units), camera, image size, sample distance and threads. Used by
vtk-compare.sh.

    vtk-volume.py --volume V.vol.toml --transfer TF.toml --size WxH --eye X,Y,Z
                  --target X,Y,Z [--up X,Y,Z] [--fov DEG] --step S --threads N
                  [--frames K] --out IMAGE.npy

Opacities are per --unit world units (Tessera's reference step, the smallest voxel spacing), so
VTK's opacity correction and Tessera's agree. Shading off, trilinear interpolation, no
automatic sample-distance adjustment, one ray per pixel. Prints `VTK_TIMES first median
fastest` (seconds per Render() call, after one untimed render) and writes the image as an
H x W x 3 float32 array, linear 0..1 from VTK's 8-bit RGB, row 0 at the top.
"""
import argparse
import statistics
import sys
import time
import tomllib

import numpy as np
import vtk
from vtk.util import numpy_support


def vec(text):
    parts = [float(p) for p in text.split(",")]
    if len(parts) != 3:
        raise argparse.ArgumentTypeError(f"{text!r} is not X,Y,Z")
    return parts


def load_volume(path):
    with open(path, "rb") as f:
        side = tomllib.load(f)
    import os

    data = os.path.join(os.path.dirname(path), side["data"])
    dtype = {"u8": "<u1", "i16": "<i2", "u16": "<u2", "f32": "<f4"}[side["type"]]
    if side.get("endian", "little") == "big":
        dtype = dtype.replace("<", ">")
    nx, ny, nz = side["dims"]
    values = np.fromfile(data, dtype=dtype)
    if values.size != nx * ny * nz:
        sys.exit(f"vtk-volume: {data} has {values.size} voxels, not {nx * ny * nz}")
    image = vtk.vtkImageData()
    image.SetDimensions(nx, ny, nz)
    image.SetSpacing(*side["spacing"])
    image.SetOrigin(*side.get("origin", [0.0, 0.0, 0.0]))
    # The fixed-point caster takes integer types up to 16 bits and float; keep the file's type.
    array = numpy_support.numpy_to_vtk(values.astype(values.dtype.newbyteorder("=")), deep=True)
    image.GetPointData().SetScalars(array)
    return image, min(side["spacing"])


def transfer(path):
    with open(path, "rb") as f:
        tf = tomllib.load(f)
    if tf.get("domain", "normalized") != "data":
        sys.exit("vtk-volume: the transfer function must be in data units (domain = \"data\")")
    color = vtk.vtkColorTransferFunction()
    opacity = vtk.vtkPiecewiseFunction()
    for p in tf["point"]:
        color.AddRGBPoint(p["value"], *p["color"])
        opacity.AddPoint(p["value"], p["opacity"])
    # Constant beyond the ends, as Tessera's.
    color.ClampingOn()
    opacity.ClampingOn()
    return color, opacity


def main():
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--volume", required=True)
    ap.add_argument("--transfer", required=True)
    ap.add_argument("--size", required=True)
    ap.add_argument("--eye", type=vec, required=True)
    ap.add_argument("--target", type=vec, required=True)
    ap.add_argument("--up", type=vec, default=[0.0, 1.0, 0.0])
    ap.add_argument("--fov", type=float, default=45.0)
    ap.add_argument("--step", type=float, required=True)
    ap.add_argument("--threads", type=int, required=True)
    ap.add_argument("--frames", type=int, default=5)
    ap.add_argument("--out", required=True)
    a = ap.parse_args()
    width, height = (int(v) for v in a.size.split("x"))

    image, unit = load_volume(a.volume)
    color, opacity = transfer(a.transfer)
    prop = vtk.vtkVolumeProperty()
    prop.SetColor(color)
    prop.SetScalarOpacity(opacity)
    prop.SetScalarOpacityUnitDistance(unit)
    prop.SetInterpolationTypeToLinear()
    prop.ShadeOff()

    mapper = vtk.vtkFixedPointVolumeRayCastMapper()
    mapper.SetInputData(image)
    mapper.SetNumberOfThreads(a.threads)
    mapper.AutoAdjustSampleDistancesOff()
    mapper.LockSampleDistanceToInputSpacingOff()
    mapper.SetSampleDistance(a.step)
    mapper.SetInteractiveSampleDistance(a.step)
    mapper.SetImageSampleDistance(1.0)
    mapper.SetMinimumImageSampleDistance(1.0)
    mapper.SetMaximumImageSampleDistance(1.0)

    volume = vtk.vtkVolume()
    volume.SetMapper(mapper)
    volume.SetProperty(prop)
    renderer = vtk.vtkRenderer()
    renderer.AddVolume(volume)
    renderer.SetBackground(0.0, 0.0, 0.0)
    camera = renderer.GetActiveCamera()
    camera.SetPosition(*a.eye)
    camera.SetFocalPoint(*a.target)
    camera.SetViewUp(*a.up)
    camera.SetViewAngle(a.fov)
    renderer.ResetCameraClippingRange()
    window = vtk.vtkRenderWindow()
    window.SetOffScreenRendering(1)
    window.AddRenderer(renderer)
    window.SetSize(width, height)
    window.SetMultiSamples(0)

    times = []
    for _ in range(a.frames + 1):
        start = time.perf_counter()
        window.Render()
        times.append(time.perf_counter() - start)
    first, timed = times[0], times[1:]
    print(f"VTK_TIMES {first:.4f} {statistics.median(timed):.4f} {min(timed):.4f}")

    grab = vtk.vtkWindowToImageFilter()
    grab.SetInput(window)
    grab.SetInputBufferTypeToRGB()
    grab.ReadFrontBufferOff()
    grab.Update()
    out = grab.GetOutput()
    w, h, _ = out.GetDimensions()
    rgb = numpy_support.vtk_to_numpy(out.GetPointData().GetScalars()).reshape(h, w, 3)
    # VTK's rows run bottom to top.
    np.save(a.out, (rgb[::-1].astype(np.float32) / 255.0))


if __name__ == "__main__":
    main()
