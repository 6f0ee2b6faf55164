"""The I/O edge: project folders in, output folders out (DESIGN section 10, docs/file-formats.md).

Only this package opens files; everything below it works on :mod:`striptri.model` arrays.
"""

from striptri.io.csvtable import CsvTable, format_csv, read_csv, write_csv
from striptri.io.output import write_output_folder
from striptri.io.project_reader import parse_project, read_project, read_settings
from striptri.io.project_writer import project_files, reader_point_order, write_project

__all__ = [
    "CsvTable",
    "format_csv",
    "parse_project",
    "project_files",
    "read_csv",
    "read_project",
    "read_settings",
    "reader_point_order",
    "write_csv",
    "write_output_folder",
    "write_project",
]
