"""Opens a blockflow run's VTK output (`blockflow run ... --vtk EVERY`) in ParaView and renders a picture.

    xvfb-run -a pvbatch scripts/paraview-view.py OUT [--step STEP] [--normal x|y|z] [--png FILE]
    paraview --script=scripts/paraview-view.py        (the GUI; the run folder from $BLOCKFLOW_RUN)

What it sets up, so that nothing has to be done by hand:
- the fluid (`OUT/fluid.pvd`): walls, cells outside the fluid and cells under a sphere are hidden
  (Threshold on the `flags` bits: fluid cells hold 1 or 3), then a slice through the middle of the
  domain normal to `--normal` (default y, a vertical plane for gravity along z), coloured by the
  velocity magnitude (lattice units);
- the spheres (`OUT/particles.pvd`): a Sphere glyph per body scaled by its `radius` array at its true
  size (the glyph source has radius 0.5, hence the factor 2), drawn light grey;
- the outline of every block, a camera looking along the normal, the last step written (or `--step`).

It writes `OUT/paraview.png` (or `--png FILE`) and prints the file's name. Under the GUI the same
pipeline stays open for the user to explore.
"""

import argparse
import os
import sys

from paraview.simple import (
    ColorBy,
    GetActiveViewOrCreate,
    GetAnimationScene,
    GetColorTransferFunction,
    GetScalarBar,
    Glyph,
    Outline,
    PVDReader,
    Render,
    SaveScreenshot,
    Show,
    Slice,
    Threshold,
)


def arguments():
    p = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    p.add_argument("out", nargs="?", default=os.environ.get("BLOCKFLOW_RUN", "out/demo"),
                   help="the run's output folder (default: $BLOCKFLOW_RUN, else out/demo)")
    p.add_argument("--step", type=float, default=None,
                   help="the time step to show (default: the last one written)")
    p.add_argument("--normal", choices=["x", "y", "z"], default="y", help="normal of the fluid slice")
    p.add_argument("--png", default=None, help="picture to write (default: OUT/paraview.png)")
    p.add_argument("--size", type=int, nargs=2, default=[1200, 1000], metavar=("W", "H"))
    # The GUI passes no arguments of its own to --script; pvbatch passes ours.
    return p.parse_args([a for a in sys.argv[1:] if not a.startswith("--script")])


def main():
    a = arguments()
    fluid_pvd = os.path.join(a.out, "fluid.pvd")
    if not os.path.exists(fluid_pvd):
        sys.exit(f"{fluid_pvd}: no VTK output here; run blockflow with --vtk EVERY first")
    fluid = PVDReader(registrationName="fluid", FileName=fluid_pvd)
    fluid.UpdatePipelineInformation()
    times = list(fluid.TimestepValues) if fluid.TimestepValues else [0.0]
    time = times[-1] if a.step is None else min(times, key=lambda t: abs(t - a.step))
    scene = GetAnimationScene()
    scene.UpdateAnimationUsingDataTimeSteps()
    scene.AnimationTime = time

    view = GetActiveViewOrCreate("RenderView")
    view.ViewSize = a.size
    view.OrientationAxesVisibility = 1
    view.Background = [1.0, 1.0, 1.0]
    # ParaView 5.11 draws the background from the palette unless told to use the colour above.
    if hasattr(view, "UseColorPaletteForBackground"):
        view.UseColorPaletteForBackground = 0

    fluid.UpdatePipeline(time)
    bounds = fluid.GetDataInformation().GetBounds()
    centre = [(bounds[2 * k] + bounds[2 * k + 1]) / 2 for k in range(3)]
    axis = "xyz".index(a.normal)
    normal = [1.0 if k == axis else 0.0 for k in range(3)]

    # Fluid cells only: flags 1 (fluid) or 3 (fluid next to a wall); walls, outside and sphere cells
    # (4, 8, 16, 32) are left out.
    fluid_only = Threshold(registrationName="fluid cells", Input=fluid)
    fluid_only.Scalars = ["CELLS", "flags"]
    if hasattr(fluid_only, "LowerThreshold"):
        fluid_only.LowerThreshold, fluid_only.UpperThreshold = 1, 3
    else:
        fluid_only.ThresholdRange = [1, 3]
    cut = Slice(registrationName="slice", Input=fluid_only)
    cut.SliceType = "Plane"
    cut.SliceType.Origin = centre
    cut.SliceType.Normal = normal
    shown = Show(cut, view)
    ColorBy(shown, ("CELLS", "velocity", "Magnitude"))
    shown.SetScalarBarVisibility(view, True)
    lut = GetColorTransferFunction("velocity")
    lut.ApplyPreset("Viridis (matplotlib)", True)
    bar = GetScalarBar(lut, view)
    bar.Title, bar.ComponentTitle = "velocity magnitude", "(lattice units)"
    bar.TitleColor = bar.LabelColor = [0.0, 0.0, 0.0]
    bar.TitleFontSize = bar.LabelFontSize = 20
    bar.ScalarBarLength = 0.4
    bar.WindowLocation = "Upper Right Corner"

    outline = Show(Outline(registrationName="blocks", Input=fluid), view)
    outline.DiffuseColor = outline.AmbientColor = [0.0, 0.0, 0.0]

    particles_pvd = os.path.join(a.out, "particles.pvd")
    if os.path.exists(particles_pvd):
        particles = PVDReader(registrationName="particles", FileName=particles_pvd)
        spheres = Glyph(registrationName="spheres", Input=particles, GlyphType="Sphere")
        spheres.ScaleArray = ["POINTS", "radius"]
        spheres.ScaleFactor = 2.0
        spheres.GlyphMode = "All Points"
        spheres.OrientationArray = ["POINTS", "No orientation array"]
        spheres.GlyphType.ThetaResolution = spheres.GlyphType.PhiResolution = 24
        s = Show(spheres, view)
        s.DiffuseColor = s.AmbientColor = [0.85, 0.85, 0.85]
        ColorBy(s, None)

    # Look along the normal at the slice, z (or y for a z normal) up.
    up = [0.0, 0.0, 1.0] if axis != 2 else [0.0, 1.0, 0.0]
    eye = list(centre)
    eye[axis] -= 4.0 * max(bounds[1] - bounds[0], bounds[3] - bounds[2], bounds[5] - bounds[4])
    view.CameraPosition = eye
    view.CameraFocalPoint = centre
    view.CameraViewUp = up
    view.CameraParallelProjection = 1
    view.ResetCamera(False)
    Render(view)
    png = a.png or os.path.join(a.out, "paraview.png")
    SaveScreenshot(png, view, ImageResolution=a.size)
    print(png)


main()
