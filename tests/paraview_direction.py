"""Open an oblique VTK-HDF file in ParaView (run by pvpython) and print what it placed, one JSON line.

    pvpython paraview_direction.py FILE.hdf

Prints ParaView's version, the image's direction matrix (row by row), the
position of its first and last points, the data bounds ParaView reports and
the centre of the occupancy's 0.5 contour.
"""

import json
import sys

from paraview import servermanager
from paraview.simple import Contour, GetParaViewVersion, OpenDataFile

reader = OpenDataFile(sys.argv[1])
reader.UpdatePipeline()
image = servermanager.Fetch(reader)
matrix = image.GetDirectionMatrix()
contour = Contour(Input=reader, ContourBy=["POINTS", "occupancy"], Isosurfaces=[0.5])
contour.UpdatePipeline()
b = contour.GetDataInformation().GetBounds()
print(json.dumps({
    "version": [GetParaViewVersion().major, GetParaViewVersion().minor],
    "direction": [matrix.GetElement(i, j) for i in range(3) for j in range(3)],
    "first": list(image.GetPoint(0)),
    "last": list(image.GetPoint(image.GetNumberOfPoints() - 1)),
    "bounds": list(reader.GetDataInformation().GetBounds()),
    "contour_centre": [(b[2 * i] + b[2 * i + 1]) / 2 for i in range(3)],
}))
