"""Instance confidence from where its masks fall in the image (paper, eq. 1-2).

Masks near the image border are often cut off or occluded, so an instance seen whole in the centre of
many frames is trusted more. The cross-agent alignment takes the most confident instance of a cluster
as its reference.

Ambiguities of the paper, and the choices made here:
- the size of the "central region" I^{c,center} is not given: it is the image minus a border of
  ``border_margin`` x width (left and right) and x height (top and bottom), 10 % by default;
- "O in I^{c,center}" is read as "every mask pixel lies in the central region" (tested on the mask's
  bounding box, which is the same thing); a mask touching the border band scores its area ratio, so
  the score jumps from S(O)/S(I) to 1 when a mask moves inward: that discontinuity is the paper's;
- T in eq. 2 is read as ALL the agent's frames (frames where the instance is absent count 0), so an
  instance seen often scores higher than one seen once, as "averaged over time" suggests.
"""

from __future__ import annotations

from typing import Sequence

import numpy as np
from scipy import ndimage

from mapping.data.frame import central_region


def frame_confidence(mask: np.ndarray, border_margin: float = 0.1) -> float:
    """Per-frame confidence C_{k,t,i} of one mask (eq. 1).

    Args:
        mask: (H, W) bool, the instance's pixels in this frame (all False when it is absent).
        border_margin: width of the border band, as a share of the image width / height.

    Returns:
        0 for an empty mask, 1 when the mask lies entirely in the central region, otherwise
        mask pixels / image pixels.
    """
    mask = np.asarray(mask)
    if mask.ndim != 2:
        raise ValueError(f"mask must be (H, W), got shape {mask.shape}")
    mask = mask.astype(bool, copy=False)
    v0, v1, u0, u1 = central_region(*mask.shape, border_margin)
    rows, cols = np.flatnonzero(mask.any(axis=1)), np.flatnonzero(mask.any(axis=0))
    if rows.size == 0:
        return 0.0
    if rows[0] >= v0 and rows[-1] < v1 and cols[0] >= u0 and cols[-1] < u1:
        return 1.0
    return float(mask.sum()) / mask.size


def label_confidences(labels: np.ndarray, border_margin: float = 0.1) -> dict[int, float]:
    """Eq. 1 for every id of a label image at once (each id's pixels form its mask).

    Args:
        labels: (H, W) non-negative int ids, 0 = no mask.
        border_margin: as in ``frame_confidence``.

    Returns:
        id -> C_{k,t,i} for every id > 0 present in ``labels``.
    """
    labels = np.asarray(labels)
    if labels.ndim != 2 or not np.issubdtype(labels.dtype, np.integer):
        raise ValueError(f"labels must be an (H, W) integer image, got {labels.dtype} {labels.shape}")
    if labels.size and labels.min() < 0:
        raise ValueError("labels must be non-negative (0 = no mask)")
    v0, v1, u0, u1 = central_region(*labels.shape, border_margin)
    areas = np.bincount(labels.ravel())
    out: dict[int, float] = {}
    for i, box in enumerate(ndimage.find_objects(labels), start=1):
        if box is None:
            continue
        inside = box[0].start >= v0 and box[0].stop <= v1 and box[1].start >= u0 and box[1].stop <= u1
        out[i] = 1.0 if inside else float(areas[i]) / labels.size
    return out


def instance_confidence(per_frame: Sequence[float], n_frames: int) -> float:
    """Instance confidence C_{k,i} (eq. 2): the mean of eq. 1 over all ``n_frames`` of the agent.

    Args:
        per_frame: C_{k,t,i} of the frames where the instance has a mask (absent frames count 0 and
            may be left out).
        n_frames: T, the number of frames of the agent.
    """
    values = np.asarray(list(per_frame), dtype=np.float64)
    if n_frames < 1:
        raise ValueError(f"n_frames must be >= 1, got {n_frames}")
    if values.size > n_frames:
        raise ValueError(f"{values.size} per-frame confidences for only {n_frames} frames")
    if values.size and (not np.all(np.isfinite(values)) or values.min() < 0 or values.max() > 1):
        raise ValueError("per-frame confidences must be finite and in [0, 1]")
    return float(values.sum() / n_frames)
