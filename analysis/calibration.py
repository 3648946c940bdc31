"""Camera calibration files: a ROS ``camera_info`` YAML or OpenCV's calibration YAML.

ROS (``camera_calibration``): ``image_width``, ``image_height``, ``camera_matrix: {rows, cols,
data}``, ``distortion_coefficients: {data}``. OpenCV (``cv::FileStorage``): a ``%YAML:1.0``
header, ``!!opencv-matrix`` nodes ``camera_matrix`` (or ``K``) and ``distortion_coefficients``
(or ``D``), ``image_width``, ``image_height``. Both give ``K`` and ``D`` (``[k1, k2, p1, p2,
k3]``, missing trailing coefficients 0) and the image size.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np
import yaml


class CalibrationError(ValueError):
    """The file is neither format, or lacks a field."""


@dataclass(frozen=True)
class Calibration:
    """Intrinsics from a calibration file: ``fx``, ``fy``, principal point, distortion, image size."""

    fx: float
    fy: float
    principal_point: tuple[float, float]
    distortion: tuple[float, ...]
    width: int
    height: int


class _Loader(yaml.SafeLoader):
    """A safe YAML loader that reads OpenCV's ``!!opencv-matrix`` as its ``data``."""


_Loader.add_constructor("tag:yaml.org,2002:opencv-matrix", lambda loader, node: loader.construct_mapping(node))


def _matrix(data: dict, *names: str) -> np.ndarray:
    for name in names:
        if name in data:
            node = data[name]
            values = node["data"] if isinstance(node, dict) else node
            return np.asarray(values, dtype=float).ravel()
    raise CalibrationError(f"no {' or '.join(names)}")


def read_calibration(path: Path) -> Calibration:
    """Read a ROS ``camera_info`` or OpenCV calibration YAML (:class:`CalibrationError` when it is
    neither)."""
    try:
        text = Path(path).read_text()
    except (OSError, UnicodeDecodeError) as exc:
        raise CalibrationError(f"cannot read {path}: {exc}") from exc
    if text.startswith("%YAML:"):  # OpenCV's header is not a YAML 1.1 directive
        text = text.split("\n", 1)[1] if "\n" in text else ""
    try:
        data = yaml.load(text, Loader=_Loader)
        if not isinstance(data, dict):
            raise CalibrationError("not a mapping")
        k = _matrix(data, "camera_matrix", "K", "k")
        d = _matrix(data, "distortion_coefficients", "D", "d")
        width, height = int(data["image_width"]), int(data["image_height"])
    except (yaml.YAMLError, KeyError, TypeError, ValueError) as exc:
        raise CalibrationError(f"{path}: neither a ROS camera_info nor an OpenCV calibration YAML ({exc})") from exc
    if k.size != 9 or (d.size > 5 and np.any(d[5:])):
        raise CalibrationError(f"{path}: K needs 9 entries and D at most 5 (the rational model is not supported)")
    distortion = tuple(float(v) for v in np.pad(d[:5], (0, 5 - min(d.size, 5))))
    return Calibration(float(k[0]), float(k[4]), (float(k[2]), float(k[5])), distortion, width, height)
