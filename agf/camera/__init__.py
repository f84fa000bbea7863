"""Camera models behind one protocol (:class:`CameraModel`), and :func:`load_camera`."""

from agf.camera.base import CameraModel
from agf.camera.double_sphere import DoubleSphere
from agf.camera.eucm import ExtendedUnified
from agf.camera.kannala_brandt import KannalaBrandt
from agf.camera.loader import load_camera
from agf.camera.ocamcalib import OCamCalib
from agf.camera.unified import Unified
from agf.camera.viewpoint_shift import ViewpointShift

__all__ = [
    "CameraModel",
    "DoubleSphere",
    "ExtendedUnified",
    "KannalaBrandt",
    "OCamCalib",
    "Unified",
    "ViewpointShift",
    "load_camera",
]
