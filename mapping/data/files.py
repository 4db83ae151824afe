"""File-level helpers shared by the dataset loaders: numbered image folders, image and matrix readers.

Every failure becomes a :class:`DatasetError` whose message starts with the offending path, because
a real scene has thousands of files and "cannot identify image file" alone does not say which one.
"""

from __future__ import annotations

import math
import re
from collections.abc import Mapping, Sequence
from pathlib import Path

import numpy as np
from PIL import Image, UnidentifiedImageError

from mapping.data.poses import rigid_pose_problem
from mapping.data.frame import Intrinsics

IMAGE_EXTS = (".png", ".jpg", ".jpeg")
_DEPTH_MODES = {"I;16", "I;16L", "I;16B", "I", "F"}
_LABEL_MODES = {"L", "P", "I;16", "I;16L", "I;16B", "I"}
_READ_ERRORS = (OSError, ValueError, SyntaxError, UnidentifiedImageError, Image.DecompressionBombError)


class DatasetError(ValueError):
    """A dataset on disk is missing, malformed or inconsistent; the message names the file."""


class DatasetWarning(UserWarning):
    """Something in a dataset was dropped or repaired (e.g. ScanNet frames with invalid poses)."""


def require_dir(path: Path, what: str) -> Path:
    """``path`` if it is a directory, else a DatasetError saying what it should hold."""
    if not path.is_dir():
        raise DatasetError(f"{path}: missing folder ({what})")
    return path


def require_file(path: Path, what: str) -> Path:
    """``path`` if it is a file, else a DatasetError saying what it should hold."""
    if not path.is_file():
        raise DatasetError(f"{path}: missing file ({what})")
    return path


def numbered_files(folder: Path, prefix: str = "", exts: Sequence[str] = IMAGE_EXTS) -> dict[int, Path]:
    """The files ``<prefix><integer><ext>`` in ``folder``, keyed by the integer, in numeric order.

    Sorting by the parsed integer (not the name) keeps ``rgb_10`` after ``rgb_9``.
    """
    require_dir(folder, f"images named {prefix}<n>{exts[0]}")
    pattern = re.compile(rf"^{re.escape(prefix)}(\d+)({'|'.join(re.escape(e) for e in exts)})$", re.IGNORECASE)
    found: dict[int, Path] = {}
    for entry in folder.iterdir():
        m = pattern.match(entry.name)
        if m is None or not entry.is_file():
            continue
        idx = int(m.group(1))
        if idx in found:
            raise DatasetError(f"{entry}: frame number {idx} also used by {found[idx].name}")
        found[idx] = entry
    if not found:
        raise DatasetError(f"{folder}: no files named {prefix}<n> with extension {'/'.join(exts)}")
    return dict(sorted(found.items()))


def match_indices(root: Path, folders: Mapping[str, Mapping[int, Path]]) -> list[int]:
    """The frame numbers present in every folder; a DatasetError naming an unmatched file otherwise.

    Args:
        root: dataset folder, for the message.
        folders: label (e.g. ``"rgb/"``) -> {frame number: path}.
    """
    sets = {label: set(files) for label, files in folders.items()}
    common = set.intersection(*sets.values())
    if all(len(s) == len(common) for s in sets.values()):
        return sorted(common)
    counts = ", ".join(f"{label} has {len(s)}" for label, s in sets.items())
    for label, files in folders.items():
        extra = sorted(set(files) - common)
        if extra:
            others = [o for o in folders if sets[o].isdisjoint({extra[0]})]
            raise DatasetError(
                f"{files[extra[0]]}: no matching frame in {', '.join(others)} "
                f"(frame counts differ under {root}: {counts})"
            )
    raise AssertionError("unreachable")  # pragma: no cover


def parse_matrix_rows(path: Path, line: str, where: str) -> np.ndarray:
    """Parse one line of 16 numbers into a row-major (4, 4) float64 matrix."""
    parts = line.replace(",", " ").split()
    if len(parts) != 16:
        raise DatasetError(f"{path}:{where}: expected 16 numbers (a row-major 4x4 pose), got {len(parts)}")
    try:
        return np.array([float(p) for p in parts], dtype=np.float64).reshape(4, 4)
    except ValueError as e:
        raise DatasetError(f"{path}:{where}: not a number ({e})") from None


def read_trajectory(path: Path) -> np.ndarray:
    """Poses of a trajectory file with one row-major 4x4 matrix per line (blank lines ignored).

    Returns:
        (n, 4, 4) float64 camera-to-world matrices, as written (no validity check).
    """
    require_file(path, "one row-major 4x4 camera-to-world pose per line")
    try:
        lines = path.read_text().splitlines()
    except (OSError, UnicodeDecodeError) as e:
        raise DatasetError(f"{path}: cannot read trajectory ({e})") from None
    poses = [parse_matrix_rows(path, ln, f"line {i + 1}") for i, ln in enumerate(lines) if ln.strip()]
    if not poses:
        raise DatasetError(f"{path}: trajectory is empty")
    return np.stack(poses)


def read_matrix_file(path: Path) -> np.ndarray:
    """A (4, 4) float64 matrix from a text file of 16 numbers (ScanNet pose and intrinsic files)."""
    try:
        text = path.read_text()
    except (OSError, UnicodeDecodeError) as e:
        raise DatasetError(f"{path}: cannot read matrix ({e})") from None
    return parse_matrix_rows(path, " ".join(text.split()), "all lines")


def check_pose(pose: np.ndarray, path: Path, where: str = "") -> None:
    """Reject poses that are not finite rigid transforms (``mapping.data.poses``): non-finite entries, a last
    row other than [0, 0, 0, 1] (e.g. column-major), a scaled or sheared rotation, a huge translation."""
    problem = rigid_pose_problem(pose)
    if problem is not None:
        raise DatasetError(f"{f'{path}:{where}' if where else path}: {problem}")


def as_intrinsics(value: Intrinsics | Mapping[str, float] | Sequence[float]) -> Intrinsics:
    """Accept an Intrinsics, a vMAP-style mapping (W/width, H/height, fx, fy, cx, cy) or a 6-sequence
    (width, height, fx, fy, cx, cy), so configs from other projects can be passed as they are."""
    if isinstance(value, Intrinsics):
        return value
    if isinstance(value, Mapping):
        low = {str(k).lower(): v for k, v in value.items()}
        try:
            w = low["width"] if "width" in low else low["w"]
            h = low["height"] if "height" in low else low["h"]
            vals = (w, h, low["fx"], low["fy"], low["cx"], low["cy"])
        except KeyError as e:
            raise ValueError(f"intrinsics mapping lacks {e}; needs W, H, fx, fy, cx, cy") from None
    else:
        vals = tuple(value)
        if len(vals) != 6:
            raise ValueError(f"intrinsics sequence must be (width, height, fx, fy, cx, cy), got {len(vals)} values")
    w, h, fx, fy, cx, cy = vals
    if not all(math.isfinite(float(v)) for v in vals) or fx <= 0 or fy <= 0 or w <= 0 or h <= 0:
        raise ValueError(f"invalid intrinsics {vals}")
    return Intrinsics(int(w), int(h), float(fx), float(fy), float(cx), float(cy))


def intrinsics_for_images(value: "Intrinsics | Mapping[str, float] | Sequence[float]",
                          size: tuple[int, int]) -> Intrinsics:
    """``as_intrinsics``, also accepting (fx, fy, cx, cy) alone, for images of ``size`` = (W, H)."""
    if not isinstance(value, (Intrinsics, Mapping)) and len(tuple(value)) == 4:
        return as_intrinsics((size[0], size[1], *tuple(value)))
    return as_intrinsics(value)


def read_cam_params(root: Path) -> tuple[dict | None, Path | None]:
    """The ``camera`` block of a Replica ``cam_params.json`` (w, h, fx, fy, cx, cy, scale) in ``root``
    or its parent (NICE-SLAM keeps one for all scenes), or (None, None) when there is none."""
    from mapping.safe_parse import load_json  # noqa: PLC0415  (bounded depth and size, no duplicated keys)

    for path in (root / "cam_params.json", root.parent / "cam_params.json"):
        if path.is_file():
            try:
                cam = load_json(path)["camera"]
                return {k: float(cam[k]) for k in ("w", "h", "fx", "fy", "cx", "cy")} | (
                    {"scale": float(cam["scale"])} if "scale" in cam else {}), path
            except (OSError, ValueError, KeyError, TypeError) as e:
                raise DatasetError(f"{path}: cannot read the camera (needs camera.w/h/fx/fy/cx/cy): {e}") from None
    return None, None


def image_size(path: Path) -> tuple[int, int]:
    """(width, height) from the image header, without decoding the pixels."""
    try:
        with Image.open(path) as im:
            return im.size
    except _READ_ERRORS as e:
        raise DatasetError(f"{path}: cannot read image ({e})") from None


def _open(path: Path, modes: set[str] | None, what: str) -> Image.Image:
    try:
        im = Image.open(path)
        im.load()
    except _READ_ERRORS as e:
        raise DatasetError(f"{path}: cannot read {what} image ({type(e).__name__}: {e})") from None
    if modes is not None and im.mode not in modes:
        raise DatasetError(f"{path}: {what} image has mode {im.mode!r}, expected single-channel {sorted(modes)}")
    return im


def _check_size(im: Image.Image, path: Path, size: tuple[int, int], what: str) -> None:
    if im.size != size:
        raise DatasetError(f"{path}: {what} image is {im.size[0]}x{im.size[1]}, expected {size[0]}x{size[1]}")


def read_rgb(path: Path, size: tuple[int, int], resize: bool = False) -> np.ndarray:
    """(H, W, 3) uint8 colour image of ``size`` = (W, H); bilinear resize when ``resize`` is set."""
    im = _open(path, None, "colour").convert("RGB")
    if resize and im.size != size:
        im = im.resize(size, Image.Resampling.BILINEAR)
    _check_size(im, path, size, "colour")
    return np.array(im, dtype=np.uint8)  # writable (torch warns on read-only arrays)


def read_depth(path: Path, size: tuple[int, int], scale: float) -> np.ndarray:
    """(H, W) float32 metres from a 16-bit depth PNG storing ``metres * scale``; 0 stays 0 (missing), and so do
    NaN, infinite and negative readings of a float image (and values that overflow float32): no NaN goes on."""
    im = _open(path, _DEPTH_MODES, "depth")
    _check_size(im, path, size, "depth")
    with np.errstate(over="ignore", invalid="ignore"):  # what overflows becomes inf, then 0 below
        depth = np.asarray(im).astype(np.float32) / np.float32(scale)
    depth[~np.isfinite(depth) | (depth < 0)] = 0.0
    return depth


def read_labels(path: Path, size: tuple[int, int], resize: bool = False) -> np.ndarray:
    """(H, W) int32 instance ids; nearest-neighbour resize (ids must not blend) when ``resize`` is set."""
    im = _open(path, _LABEL_MODES, "instance")
    if resize and im.size != size:
        im = im.resize(size, Image.Resampling.NEAREST)
    _check_size(im, path, size, "instance")
    return np.asarray(im).astype(np.int32)
