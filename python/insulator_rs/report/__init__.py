"""The inspection report: the folder a run writes and what a line crew takes from it
(photos with EXIF GPS, insulators in WGS-84, GeoJSON and KML map layers)."""

from insulator_rs.report.clock import FlightClock
from insulator_rs.report.exif import compass_heading_deg
from insulator_rs.report.folder import ReportFolder, check_out_folder, parse_out_folder
from insulator_rs.report.writer import ReportWriter

__all__ = ["FlightClock", "ReportFolder", "ReportWriter", "check_out_folder", "compass_heading_deg",
           "parse_out_folder"]
