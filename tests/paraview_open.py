"""Open files by name in ParaView (run by pvpython) and print what it read, one JSON line.

    pvpython paraview_open.py FILE...
"""

import json
import sys

from paraview import servermanager
from paraview.simple import GetParaViewVersion, OpenDataFile
from vtkmodules.util.numpy_support import vtk_to_numpy

report = {"version": [GetParaViewVersion().major, GetParaViewVersion().minor], "files": {}}
for path in sys.argv[1:]:
    try:
        reader = OpenDataFile(path)
    except RuntimeError as exc:  # "No reader found for ..."
        report["files"][path] = {"error": str(exc)}
        continue
    reader.UpdatePipeline()
    info = reader.GetDataInformation()
    data = servermanager.Fetch(reader)
    pd = data.GetPointData()
    arrays = {pd.GetArrayName(i): vtk_to_numpy(pd.GetArray(i)).tolist() for i in range(pd.GetNumberOfArrays())}
    report["files"][path] = {"reader": reader.GetXMLName(), "extent": list(info.GetExtent()),
                             "bounds": list(info.GetBounds()), "arrays": arrays}
print(json.dumps(report))
