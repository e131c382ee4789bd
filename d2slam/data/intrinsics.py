"""Camera intrinsics of the TUM RGB-D benchmark (freiburg1/2/3) and how a sequence picks one.

Values are the ones published on the TUM RGB-D "file formats" page (ROS default calibration for the colour camera
of each Kinect) and used by ORB-SLAM3's ``TUM1.yaml`` / ``TUM2.yaml`` / ``TUM3.yaml``: 640x480, depth factor 5000
(a 16-bit depth PNG value of 5000 is 1 m), ``bf`` = 40 (virtual stereo baseline times fx, ORB-SLAM convention).
freiburg3 images are already undistorted by the dataset (no distortion); freiburg1/2 carry OpenCV
(k1, k2, p1, p2, k3) coefficients. Images are never undistorted by the readers: the engine undistorts keypoints.
"""

from __future__ import annotations

import re
from pathlib import Path

from d2slam.data.base import Camera
from d2slam.errors import D2SlamError

#: TUM depth PNG scale: depth in metres = PNG value / DEPTH_FACTOR.
TUM_DEPTH_FACTOR = 5000.0
#: ORB-SLAM3 TUM yaml ``Camera.bf``.
TUM_BF = 40.0

FREIBURG1 = Camera(fx=517.3, fy=516.5, cx=318.6, cy=255.3, width=640, height=480,
                   dist=(0.2624, -0.9531, -0.0054, 0.0026, 1.1633),
                   depth_factor=TUM_DEPTH_FACTOR, bf=TUM_BF, name="freiburg1")
FREIBURG2 = Camera(fx=520.9, fy=521.0, cx=325.1, cy=249.7, width=640, height=480,
                   dist=(0.2312, -0.7849, -0.0033, -0.0001, 0.9172),
                   depth_factor=TUM_DEPTH_FACTOR, bf=TUM_BF, name="freiburg2")
FREIBURG3 = Camera(fx=535.4, fy=539.2, cx=320.1, cy=247.6, width=640, height=480,
                   dist=(0.0, 0.0, 0.0, 0.0, 0.0),
                   depth_factor=TUM_DEPTH_FACTOR, bf=TUM_BF, name="freiburg3")

CAMERAS: dict[str, Camera] = {"freiburg1": FREIBURG1, "freiburg2": FREIBURG2, "freiburg3": FREIBURG3}

# "freiburg3", "fr3", "FR_3", "fr-3" not preceded by a letter and not followed by a digit.
_NAME_RE = re.compile(r"(?<![a-z])(?:freiburg|fr)[_\-]?([123])(?![0-9])", re.IGNORECASE)


def camera_by_name(name: str) -> Camera:
    """``"fr1"``, ``"freiburg1"``, ``"1"`` (any case) -> the freiburg camera; anything else -> D2SlamError."""
    key = str(name).strip().lower()
    if key in ("1", "2", "3"):
        return CAMERAS[f"freiburg{key}"]
    m = _NAME_RE.fullmatch(key)
    if m is None:
        raise D2SlamError(f"unknown camera {name!r}: expected one of fr1, fr2, fr3 (or freiburg1/2/3)")
    return CAMERAS[f"freiburg{m.group(1)}"]


def camera_from_folder(path: str | Path) -> Camera:
    """Pick the freiburg camera from a sequence folder name (``rgbd_dataset_freiburg3_walking_xyz``,
    ``fr1_desk``, ...). A name that names no freiburg camera, or names two different ones, is an error that asks
    for an explicit camera."""
    name = Path(path).name
    found = {m.group(1) for m in _NAME_RE.finditer(name)}
    if len(found) == 1:
        return CAMERAS[f"freiburg{found.pop()}"]
    what = "names no freiburg camera" if not found else f"names several cameras ({', '.join(sorted(found))})"
    raise D2SlamError(f"cannot tell the camera: the folder name {name!r} {what}; give it explicitly "
                      "(--camera fr1|fr2|fr3, or camera= in Python)", path=path)


def resolve_camera(camera: Camera | str | None, root: str | Path) -> Camera:
    """``camera`` as given (a ``Camera`` or a name for :func:`camera_by_name`), else from the folder name."""
    if camera is None:
        return camera_from_folder(root)
    if isinstance(camera, Camera):
        return camera
    if isinstance(camera, str):
        return camera_by_name(camera)
    raise D2SlamError(f"camera must be a Camera, a name (fr1/fr2/fr3) or None, not {type(camera).__name__}")
