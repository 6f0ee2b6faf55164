"""Formats people already have (docs/formats.md): BAL problems, COLMAP text models and DBAT script
projects, read into
struct-of-arrays records and converted to and from :class:`striptri.model.Project`.

* :mod:`striptri.formats.bal` - BAL reader and the BAL cost function;
* :mod:`striptri.formats.colmap` - COLMAP cameras.txt / images.txt / points3D.txt reader and writer;
* :mod:`striptri.formats.dbat` - DBAT script projects (camera, measurements, control, datum) <-> project:
  ``xml_tree``, ``reader``, ``to_project``, ``writer``;
* :mod:`striptri.formats.conversions` - BAL -> project, COLMAP <-> project (no file I/O);
* :mod:`striptri.formats.scene` - what every conversion returns (Scene) and the minimal datum by photos;
* :mod:`striptri.formats.convert` - the ``striptri convert`` pipeline.
"""

from striptri.formats.bal import (
    BalProblem,
    bal_cost,
    bal_text,
    bal_predict,
    bal_residuals,
    read_bal,
)
from striptri.formats.colmap import ColmapModel, colmap_files, read_colmap
from striptri.formats.conversions import (
    ColmapNames,
    approximate_points,
    bal_to_project,
    colmap_to_project,
    project_to_bal,
    project_to_colmap,
)
from striptri.formats.convert import ConvertResult, convert, detect_format, read_scene
from striptri.formats.dbat import DbatCamera, DbatProject, dbat_files, dbat_to_project, read_dbat, read_dbat_camera
from striptri.formats.scene import Scene

__all__ = [
    "BalProblem", "ColmapModel", "ColmapNames", "ConvertResult", "DbatCamera", "DbatProject", "Scene",
    "approximate_points", "bal_cost", "bal_text", "dbat_files", "dbat_to_project", "project_to_bal", "read_dbat",
    "read_dbat_camera",
    "bal_predict", "bal_residuals", "bal_to_project", "colmap_files", "colmap_to_project", "convert",
    "detect_format", "project_to_colmap", "read_bal", "read_colmap", "read_scene",
]
