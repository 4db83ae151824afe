"""The optional image-text (CLIP-like) encoder of mask crops, loaded only from a local checkpoint.

No CLIP weights ship in any PyPI package and nothing is downloaded at run time, so the visual term
is optional: without a checkpoint ``load_image_encoder`` says so once per process and returns None,
and retrieval gives the visual similarity weight 0. With one, ``OpenClipEncoder`` runs open_clip
(``pip install openmulti[clip]``) on crops padded by 20 px around each mask, as OpenObj does.
"""

from __future__ import annotations

import warnings
from pathlib import Path
from typing import Protocol, Sequence

import numpy as np

CLIP_EXTRA_HINT = "pip install openmulti[clip]"
CROP_PAD_PX = 20  # OpenObj pads mask crops by 20 pixels


class ImageEncoderError(RuntimeError):
    """The image-text encoder cannot be loaded or used."""


class VisualFeatureNotice(UserWarning):
    """No image-text encoder: visual features are absent and weigh 0 in retrieval."""


class ImageTextEncoder(Protocol):
    """An image-text embedding model (CLIP-like) with a shared feature space."""

    dim: int
    """Feature dimension D."""

    def encode_images(self, crops: list[np.ndarray]) -> np.ndarray:
        """(n, D) float32 unit features of (h, w, 3) uint8 crops."""
        ...

    def encode_texts(self, texts: Sequence[str]) -> np.ndarray:
        """(n, D) float32 unit features of texts."""
        ...


def crop_for_mask(rgb: np.ndarray, mask: np.ndarray, pad_px: int = CROP_PAD_PX) -> np.ndarray:
    """The image inside the mask's bounding box grown by ``pad_px`` on each side (clipped to the image).

    Args:
        rgb : (H, W, 3) uint8 image.
        mask : (H, W) bool mask with at least one pixel.
        pad_px : padding in pixels (>= 0).

    Returns:
        (h, w, 3) uint8 crop (a copy).
    """
    rgb, mask = np.asarray(rgb), np.asarray(mask, bool)
    if rgb.ndim != 3 or rgb.shape[2] != 3 or mask.shape != rgb.shape[:2]:
        raise ValueError(f"crop_for_mask: rgb must be (H, W, 3) and mask (H, W); got {rgb.shape} and {mask.shape}")
    if pad_px < 0:
        raise ValueError(f"crop_for_mask: pad_px must be >= 0, got {pad_px}")
    rows, cols = np.nonzero(mask)
    if len(rows) == 0:
        raise ValueError("crop_for_mask: the mask is empty")
    r0, r1 = max(rows.min() - pad_px, 0), min(rows.max() + 1 + pad_px, mask.shape[0])
    c0, c1 = max(cols.min() - pad_px, 0), min(cols.max() + 1 + pad_px, mask.shape[1])
    return rgb[r0:r1, c0:c1].copy()


def _unit_rows(x: np.ndarray) -> np.ndarray:
    norms = np.linalg.norm(x, axis=1, keepdims=True)
    if np.any(norms == 0) or not np.all(np.isfinite(norms)):
        raise ImageEncoderError("the image-text encoder returned a zero or non-finite feature")
    return (x / norms).astype(np.float32)


class OpenClipEncoder:
    """open_clip model loaded from a local checkpoint file (never downloaded).

    Args:
        checkpoint_path: the ``.pt`` / ``.bin`` / ``.safetensors`` weights of ``model_name``.
        model_name: open_clip architecture name ("ViT-B-32", 512-d as in OpenObj).
        device: torch device.
    """

    def __init__(self, checkpoint_path: str | Path, model_name: str = "ViT-B-32", device: str = "cpu"):
        path = Path(checkpoint_path).expanduser()
        if not path.is_file():
            raise FileNotFoundError(f"image-text encoder checkpoint not found: {path}")
        try:
            import open_clip  # noqa: PLC0415 (optional dependency)
        except ImportError as exc:
            raise ImageEncoderError(f"OpenClipEncoder needs the optional package open-clip-torch: "
                                    f"{CLIP_EXTRA_HINT}") from exc
        import torch  # noqa: PLC0415

        self._torch = torch
        self.device = device
        try:
            model, _, preprocess = open_clip.create_model_and_transforms(model_name, pretrained=str(path),
                                                                         device=device)
        except Exception as exc:  # name the file instead of a deep loader trace
            raise ImageEncoderError(f"could not load {model_name} weights from {path}: {exc}") from exc
        self._model = model.eval()
        self._preprocess = preprocess
        self._tokenizer = open_clip.get_tokenizer(model_name)
        with torch.no_grad():
            self.dim = int(self._model.encode_text(self._tokenizer(["a"]).to(device)).shape[-1])

    def encode_images(self, crops: list[np.ndarray]) -> np.ndarray:
        """(n, D) float32 unit features of (h, w, 3) uint8 crops."""
        if not crops:
            return np.zeros((0, self.dim), np.float32)
        from PIL import Image  # noqa: PLC0415

        batch = self._torch.stack([self._preprocess(Image.fromarray(np.asarray(c, np.uint8))) for c in crops])
        with self._torch.no_grad():
            features = self._model.encode_image(batch.to(self.device)).float().cpu().numpy()
        return _unit_rows(features)

    def encode_texts(self, texts: Sequence[str]) -> np.ndarray:
        """(n, D) float32 unit features of texts."""
        if not texts:
            return np.zeros((0, self.dim), np.float32)
        with self._torch.no_grad():
            features = self._model.encode_text(self._tokenizer([str(t) for t in texts]).to(self.device))
        return _unit_rows(features.float().cpu().numpy())


_notice_given = False  # the "no image encoder" notice is said once per process


def load_image_encoder(checkpoint: str | Path | None, model_name: str = "ViT-B-32",
                       device: str = "cpu") -> ImageTextEncoder | None:
    """An ``OpenClipEncoder`` for ``checkpoint``, or None (with a one-time notice) when there is none.

    Raises:
        FileNotFoundError: ``checkpoint`` is given but is not a file.
        ImageEncoderError: open_clip is not installed, or the weights do not load.
    """
    global _notice_given
    if checkpoint is None or str(checkpoint) == "":
        if not _notice_given:
            _notice_given = True
            warnings.warn("no image-text (CLIP) checkpoint given: masks get no visual feature and the visual "
                          "term weighs 0 in retrieval (give a local open_clip checkpoint and "
                          f"`{CLIP_EXTRA_HINT}` to use one)", VisualFeatureNotice, stacklevel=2)
        return None
    return OpenClipEncoder(checkpoint, model_name=model_name, device=device)
