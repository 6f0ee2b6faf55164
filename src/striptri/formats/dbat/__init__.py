"""DBAT (Damped Bundle Adjustment Toolbox, Börlin & Grussenmeyer) script projects <-> striptri
projects (docs/formats.md, section DBAT). Malformed input: InputError naming the file and the line.

* :mod:`.xml_tree` - the XML read safely, as an element tree with line numbers;
* :mod:`.reader` - a script (and its camera and text files) -> :class:`DbatProject`;
* :mod:`.to_project` - :class:`DbatProject` -> striptri project (pixel and camera conventions);
* :mod:`.writer` - striptri project -> the files of a DBAT script project.
"""

from striptri.formats.dbat.reader import (
    DISTORTION_NAMES,
    IO_NAMES,
    DbatCamera,
    DbatProject,
    read_dbat,
    read_dbat_camera,
    script_inputs,
)
from striptri.formats.dbat.to_project import (
    ELEMENT_OF,
    dbat_to_project,
    pixels_to_plate,
    plate_origin,
    striptri_camera,
)
from striptri.formats.dbat.writer import SCRIPT_FILE, dbat_files
from striptri.formats.scene import photo_datum

__all__ = [
    "DISTORTION_NAMES", "ELEMENT_OF", "IO_NAMES", "SCRIPT_FILE", "DbatCamera", "DbatProject", "dbat_files",
    "dbat_to_project", "photo_datum", "pixels_to_plate", "plate_origin", "read_dbat", "read_dbat_camera",
    "script_inputs",
    "striptri_camera",
]
