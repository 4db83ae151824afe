"""What a camera pose must be before anything is computed from it: a finite rigid transform.

A pose with a scaled or sheared rotation, or a huge entry, does not fail loudly downstream: points
overflow to inf and an SVD spins for minutes. Data files and ray messages are checked here alike.
"""

from __future__ import annotations

import numpy as np

ROTATION_TOLERANCE = 1e-3
"""Largest entry of |R^T R - I| accepted (text files with 6 decimals and float32 stay far below)."""
MAX_TRANSLATION_M = 1e5
"""Largest camera position accepted, in metres (a building is under 1e3)."""


def rigid_pose_problem(pose: np.ndarray) -> str | None:
    """Why the (4, 4) camera-to-world ``pose`` is not a finite rigid transform, or None if it is."""
    pose = np.asarray(pose)
    if pose.shape != (4, 4):
        return f"pose has shape {pose.shape}, expected (4, 4)"
    if not np.all(np.isfinite(pose)):
        return "pose has non-finite entries (nan/inf)"
    if not np.allclose(pose[3], [0.0, 0.0, 0.0, 1.0], atol=1e-6):
        return f"last pose row is {pose[3].tolist()}, expected [0, 0, 0, 1] (column-major file?)"
    if np.max(np.abs(pose[:3, 3])) > MAX_TRANSLATION_M:
        return f"camera position {pose[:3, 3].tolist()} lies over {MAX_TRANSLATION_M:g} m away"
    rotation = pose[:3, :3].astype(np.float64)
    if np.max(np.abs(rotation)) > 1.0 + ROTATION_TOLERANCE:
        return "rotation has an entry beyond 1 (not a rotation: scaled or sheared)"
    error = float(np.max(np.abs(rotation.T @ rotation - np.eye(3))))
    if error > ROTATION_TOLERANCE:
        return f"rotation is not orthonormal (|R^T R - I| = {error:.2g}: scaled or sheared)"
    if np.linalg.det(rotation) < 0:
        return "rotation is a reflection (determinant -1: left-handed axes?)"
    return None
