"""Camera intrinsics of the TUM RGB-D benchmark (freiburg1/2/3) and how a sequence picks one.

Any other RGB-D camera comes from an ORB-SLAM3 settings YAML (:func:`read_camera_file`, ``--camera FILE``).

Values are the ones published on the TUM RGB-D "file formats" page (ROS default calibration for the colour camera
of each Kinect) and used by ORB-SLAM3's ``TUM1.yaml`` / ``TUM2.yaml`` / ``TUM3.yaml``: 640x480, depth factor 5000
(a 16-bit depth PNG value of 5000 is 1 m), ``bf`` = 40 (virtual stereo baseline times fx, ORB-SLAM convention).
freiburg3 images are already undistorted by the dataset (no distortion); freiburg1/2 carry OpenCV
(k1, k2, p1, p2, k3) coefficients. Images are never undistorted by the readers: the engine undistorts keypoints.
"""

from __future__ import annotations

import math
import re
from dataclasses import dataclass
from pathlib import Path

import yaml

from d2slam.data.base import Camera
from d2slam.errors import D2SlamError, read_text

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
        raise D2SlamError(f"unknown camera {name!r}: expected one of fr1, fr2, fr3 (or freiburg1/2/3) or an "
                          "ORB-SLAM3 RGB-D settings file (.yaml)")
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
                      "(--camera fr1|fr2|fr3 or --camera SETTINGS.yaml, or camera= in Python)", path=path)


@dataclass(frozen=True)
class CameraSettings:
    """What an ORB-SLAM3 RGB-D settings file says: the camera and its close-point threshold (``ThDepth``, None
    when the file has none)."""

    camera: Camera
    th_depth: float | None


# ORB-SLAM3 keys: the newer ``Camera1.*`` / ``Stereo.*`` / ``RGBD.*`` names first, then the older ones.
_KEYS = {
    "fx": ("Camera1.fx", "Camera.fx"), "fy": ("Camera1.fy", "Camera.fy"),
    "cx": ("Camera1.cx", "Camera.cx"), "cy": ("Camera1.cy", "Camera.cy"),
    "k1": ("Camera1.k1", "Camera.k1"), "k2": ("Camera1.k2", "Camera.k2"), "p1": ("Camera1.p1", "Camera.p1"),
    "p2": ("Camera1.p2", "Camera.p2"), "k3": ("Camera1.k3", "Camera.k3"),
    "width": ("Camera.width", "Camera1.width"), "height": ("Camera.height", "Camera1.height"),
    "depth_factor": ("RGBD.DepthMapFactor", "DepthMapFactor"), "th_depth": ("Stereo.ThDepth", "ThDepth"),
    "bf": ("Camera.bf",), "b": ("Stereo.b",),
}


def _yaml_loader():
    class Loader(yaml.SafeLoader):
        """SafeLoader that reads OpenCV's tagged values (``!!opencv-matrix``) as plain mappings."""

    Loader.add_multi_constructor("", lambda loader, suffix, node: (
        loader.construct_mapping(node) if isinstance(node, yaml.MappingNode) else loader.construct_scalar(node)))
    return Loader


def read_camera_file(path: str | Path) -> CameraSettings:
    """An ORB-SLAM3 RGB-D settings YAML -> :class:`CameraSettings`. Reads ``Camera.fx/fy/cx/cy``, distortion
    ``k1 k2 p1 p2 [k3]``, ``Camera.width/height``, ``Camera.bf``, ``DepthMapFactor`` and ``ThDepth`` (ORB-SLAM2 and
    ORB-SLAM3 0.x), or ``Camera1.*``, ``Stereo.b`` (bf = b fx), ``RGBD.DepthMapFactor`` and ``Stereo.ThDepth``
    (ORB-SLAM3 1.0). The ``%YAML:1.0`` first line of OpenCV files is accepted. Only pinhole cameras."""
    path = Path(path).expanduser()
    text = read_text(path, "camera settings")
    text = re.sub(r"\A\s*%YAML[: ]\s*\d+\.\d+[^\n]*\n", "", text)  # OpenCV's directive; PyYAML wants "%YAML 1.1"
    try:
        data = yaml.load(text, Loader=_yaml_loader())
    except yaml.YAMLError as exc:
        mark = getattr(exc, "problem_mark", None)
        raise D2SlamError(f"not a YAML file: {getattr(exc, 'problem', None) or exc}", path=path,
                          line=mark.line + 1 if mark is not None else None) from None
    if not isinstance(data, dict):
        raise D2SlamError("camera settings must be a YAML mapping of ORB-SLAM3 keys (Camera.fx: ...)", path=path)
    kind = str(data.get("Camera.type", "PinHole")).strip('"')
    if kind != "PinHole":
        raise D2SlamError(f"Camera.type {kind!r}: only PinHole RGB-D cameras are supported", path=path)

    def value(field: str):
        for key in _KEYS[field]:
            if key in data:
                try:
                    v = float(data[key])
                except (TypeError, ValueError):
                    raise D2SlamError(f"{key} must be a number, not {data[key]!r}", path=path) from None
                if not math.isfinite(v):
                    raise D2SlamError(f"{key} must be finite", path=path)
                return v
        return None

    vals = {f: value(f) for f in _KEYS}
    need = [f for f in ("fx", "fy", "cx", "cy", "width", "height", "depth_factor") if vals[f] is None]
    if vals["bf"] is None and vals["b"] is None:
        need.append("bf")
    if need:
        raise D2SlamError("camera settings lack " + ", ".join(_KEYS[f][-1] for f in need)
                          + " (ORB-SLAM3 RGB-D keys, old Camera.* or new Camera1.* names)", path=path)
    if min(vals["fx"], vals["fy"], vals["width"], vals["height"], vals["depth_factor"]) <= 0:
        raise D2SlamError("fx, fy, width, height and DepthMapFactor must be positive", path=path)
    bf = vals["bf"] if vals["bf"] is not None else vals["b"] * vals["fx"]
    camera = Camera(fx=vals["fx"], fy=vals["fy"], cx=vals["cx"], cy=vals["cy"], width=int(vals["width"]),
                    height=int(vals["height"]), dist=tuple(vals[k] or 0.0 for k in ("k1", "k2", "p1", "p2", "k3")),
                    depth_factor=vals["depth_factor"], bf=bf, name=path.stem)
    return CameraSettings(camera, vals["th_depth"])


def is_camera_file(camera) -> bool:
    """A ``--camera`` value that names a settings file (a ``.yaml``/``.yml`` path or an existing file)."""
    return isinstance(camera, (str, Path)) and (str(camera).lower().endswith((".yaml", ".yml"))
                                                 or Path(camera).expanduser().is_file())


def resolve_camera(camera: Camera | str | Path | None, root: str | Path) -> Camera:
    """``camera`` as given (a ``Camera``, a name for :func:`camera_by_name` or an ORB-SLAM3 settings file for
    :func:`read_camera_file`), else from the folder name."""
    if camera is None:
        return camera_from_folder(root)
    if isinstance(camera, Camera):
        return camera
    if is_camera_file(camera):
        return read_camera_file(camera).camera
    if isinstance(camera, str):
        return camera_by_name(camera)
    raise D2SlamError(f"camera must be a Camera, a name (fr1/fr2/fr3), a settings file or None, not "
                      f"{type(camera).__name__}")
