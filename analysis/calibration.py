"""Camera calibration files: a ROS ``camera_info`` YAML or OpenCV's calibration YAML.

ROS (``camera_calibration``): ``image_width``, ``image_height``, ``camera_matrix: {rows, cols,
data}``, ``distortion_model``, ``distortion_coefficients: {data}``; a ``sensor_msgs/CameraInfo``
message as ``ros2 topic echo`` prints it (``width``, ``height``, ``k``, ``distortion_model``,
``d``, then ``---``) reads too. OpenCV (``cv::FileStorage``): a ``%YAML:1.0`` header,
``!!opencv-matrix`` nodes ``camera_matrix`` (or ``K``) and ``distortion_coefficients`` (or ``D``),
``image_width``, ``image_height``. Both give ``K`` (a pinhole matrix without skew) and ``D``
(``[k1, k2, p1, p2, k3]``, missing trailing coefficients 0) and the image size. Every problem
is one line naming the file and the field.
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


SUPPORTED_MODELS = ("plumb_bob", "rational_polynomial")
"""ROS ``distortion_model`` names read: ``plumb_bob`` (OpenCV's ``[k1, k2, p1, p2, k3]``) and
``rational_polynomial`` with ``k4 = k5 = k6 = 0`` (the same model)."""

_SUPPORTED = (
    "supported: plumb_bob, OpenCV's 5 coefficients [k1, k2, p1, p2, k3], and rational_polynomial with "
    "k4 = k5 = k6 = 0"
)


def _field(data: dict, names: tuple[str, ...], what: str) -> object:
    """The value of the first of ``names`` in ``data`` (refused, naming them, when none is there)."""
    for name in names:
        if name in data:
            return data[name]
    others = f" (or {', '.join(names[1:])})" if len(names) > 1 else ""
    raise CalibrationError(f"missing field {names[0]}{others}: {what}")


def _numbers(data: dict, names: tuple[str, ...], what: str) -> np.ndarray:
    """A matrix field (a list, or a mapping with ``data``) as a flat float array."""
    node = _field(data, names, what)
    name = next(n for n in names if n in data)
    values = node.get("data") if isinstance(node, dict) else node
    if not isinstance(values, list) or not all(
        isinstance(v, int | float) and not isinstance(v, bool) for v in np.ravel(np.asarray(values, dtype=object))
    ):
        raise CalibrationError(f"{name}: expected a list of numbers (or a mapping with data = [...]), got {node!r}")
    return np.asarray(values, dtype=float).ravel()


def _pixels(data: dict, names: tuple[str, str], what: str) -> int:
    value = _field(data, names, what)
    if isinstance(value, bool) or not isinstance(value, int) or value <= 0:
        raise CalibrationError(f"{next(n for n in names if n in data)}: expected a positive whole number of pixels, "
                               f"got {value!r}")  # fmt: skip
    return value


def _intrinsics(k: np.ndarray) -> tuple[float, float, float, float]:
    """``fx, fy, cx, cy`` of a 3x3 pinhole matrix ``[[fx, 0, cx], [0, fy, cy], [0, 0, 1]]``."""
    if k.size != 9:
        raise CalibrationError(f"camera_matrix: expected 9 entries (a 3x3 matrix, row by row), got {k.size}")
    if not np.all(np.isfinite(k)) or k[0] <= 0 or k[4] <= 0:
        raise CalibrationError(f"camera_matrix: fx and fy (entries 0 and 4) must be positive and finite, got {k[0]:g}, "
                               f"{k[4]:g}")  # fmt: skip
    if k[1] != 0 or k[3] != 0 or k[6] != 0 or k[7] != 0 or k[8] != 1:
        raise CalibrationError(
            "camera_matrix: expected a pinhole matrix [fx, 0, cx, 0, fy, cy, 0, 0, 1] (no skew), got "
            f"[{', '.join(f'{v:g}' for v in k)}]"
        )
    return float(k[0]), float(k[4]), float(k[2]), float(k[5])


def _distortion(data: dict) -> tuple[float, ...]:
    """``[k1, k2, p1, p2, k3]`` of a supported distortion model (:data:`SUPPORTED_MODELS`)."""
    model = data.get("distortion_model")
    if model is not None and model not in SUPPORTED_MODELS:
        raise CalibrationError(f"distortion_model: {model!r} is not supported ({_SUPPORTED})")
    d = _numbers(data, ("distortion_coefficients", "D", "d"), "the distortion coefficients [k1, k2, p1, p2, k3]")
    if d.size > 5 and np.any(d[5:]):
        raise CalibrationError(
            f"distortion_coefficients: {d.size} coefficients with nonzero entries past the fifth (a rational, "
            f"thin-prism or tilted model) are not supported ({_SUPPORTED})"
        )
    if not np.all(np.isfinite(d)):
        raise CalibrationError("distortion_coefficients: every coefficient must be finite")
    return tuple(float(v) for v in np.pad(d[:5], (0, 5 - min(d.size, 5))))


def _document(text: str) -> dict:
    """The one mapping of a YAML text (a trailing ``---`` allowed), or one line of why not."""
    try:
        documents = [d for d in yaml.load_all(text, Loader=_Loader) if d is not None]
    except yaml.MarkedYAMLError as exc:
        mark = exc.problem_mark or exc.context_mark
        where = f"line {mark.line + 1}, column {mark.column + 1}: " if mark is not None else ""
        raise CalibrationError(f"not valid YAML: {where}{exc.problem or exc.context}") from None
    except yaml.YAMLError as exc:
        raise CalibrationError(f"not valid YAML: {' '.join(str(exc).split())}") from None
    if len(documents) != 1 or not isinstance(documents[0], dict):
        raise CalibrationError("expected one YAML mapping (a ROS camera_info or an OpenCV calibration file)")
    return documents[0]


def read_calibration(path: Path) -> Calibration:
    """Read a ROS ``camera_info`` or OpenCV calibration YAML.

    Raises
    ------
    CalibrationError
        One line naming the file and the problem: unreadable, not YAML (with its line and
        column), a missing or malformed field, or a distortion model that is not supported.
    """
    try:
        text = Path(path).read_text()
    except (OSError, UnicodeDecodeError) as exc:
        raise CalibrationError(f"cannot read {path}: {exc}") from exc
    if text.startswith("%YAML:"):  # OpenCV's header is not a YAML 1.1 directive (a comment keeps line numbers)
        text = "#" + text
    try:
        data = _document(text)
        fx, fy, cx, cy = _intrinsics(_numbers(data, ("camera_matrix", "K", "k"), "the 3x3 camera matrix"))
        distortion = _distortion(data)
        width = _pixels(data, ("image_width", "width"), "the image width in pixels")
        height = _pixels(data, ("image_height", "height"), "the image height in pixels")
    except CalibrationError as exc:
        raise CalibrationError(f"{path}: {exc}") from None
    return Calibration(fx, fy, (cx, cy), distortion, width, height)
