"""``load_dataset``, the one entry point for real RGB-D scenes, and layout detection.

The dataset classes live in ``dataset``; the layout loaders in ``replica`` and ``scannet``. The
names ``FrameFiles``, ``ReadSpec``, ``LazyFrames``, ``RGBDDataset``, ``select`` and
``check_depth_scale`` are re-exported here for code that imported them from this module.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

from mapping.data.files import DatasetError
from mapping.data.dataset import FrameFiles, LazyFrames, ReadSpec, RGBDDataset, check_depth_scale, select
from mapping.data.replica import load_nice_slam, load_replica
from mapping.data.scannet import load_scannet

__all__ = ["FrameFiles", "LAYOUT_MARKERS", "LazyFrames", "ReadSpec", "RGBDDataset", "check_depth_scale",
           "detect_layout", "load_dataset", "select"]

LOADERS = {"replica": load_replica, "nice_slam": load_nice_slam, "scannet": load_scannet}


# --------------------------------------------------------------------------- layout detection

#: kind -> (marker name, is a folder) that a scene folder of that layout must contain.
LAYOUT_MARKERS: dict[str, tuple[tuple[str, bool], ...]] = {
    "replica": (("rgb", True), ("depth", True), ("traj_w_c.txt", False)),
    "nice_slam": (("results", True), ("traj.txt", False)),
    "scannet": (("color", True), ("depth", True), ("pose", True)),
}


def _missing_markers(root: Path, kind: str) -> list[str]:
    out = []
    for name, is_dir in LAYOUT_MARKERS[kind]:
        p = root / name
        if not (p.is_dir() if is_dir else p.is_file()):
            out.append(name + ("/" if is_dir else ""))
    return out


def detect_layout(path: str | Path) -> str:
    """The layout of the scene folder ``path``: ``"replica"`` (vMAP), ``"nice_slam"`` or ``"scannet"``.

    Raises:
        DatasetError: nothing or more than one layout matches; the message lists what was looked for.
    """
    root = Path(path)
    if not root.is_dir():
        raise DatasetError(f"{root}: dataset folder does not exist")
    missing = {kind: _missing_markers(root, kind) for kind in LAYOUT_MARKERS}
    found = [kind for kind, m in missing.items() if not m]
    if len(found) == 1:
        return found[0]
    if found:
        raise DatasetError(f"{root}: ambiguous layout, matches {found}; pass kind= explicitly")
    looked = "; ".join(
        f"{kind} needs {', '.join(n + ('/' if d else '') for n, d in LAYOUT_MARKERS[kind])} "
        f"(missing {', '.join(missing[kind])})"
        for kind in LAYOUT_MARKERS
    )
    raise DatasetError(f"{root}: no known dataset layout found. Looked for: {looked}")


def load_dataset(path: str | Path, kind: str = "auto", **kw: Any) -> RGBDDataset:
    """Load a real RGB-D scene of any supported layout.

    Args:
        path: the scene folder (e.g. ``Replica/room0`` of NICE-SLAM, ``vmap/room_0/imap/00``, or a
            ScanNet export ``scene0000_00``).
        kind: ``"auto"`` (detect), ``"replica"``, ``"nice_slam"`` or ``"scannet"``.
        **kw: passed to the layout's loader (``depth_scale``, ``intrinsics``, ``stride``,
            ``max_frames``, ``instances``, and for ScanNet ``invalid_pose``).
    """
    if kind == "auto":
        kind = detect_layout(path)
    if kind not in LOADERS:
        raise ValueError(f"kind must be 'auto' or one of {sorted(LOADERS)}, got {kind!r}")
    return LOADERS[kind](path, **kw)
