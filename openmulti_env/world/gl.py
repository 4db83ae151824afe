"""The one place that imports pyrender: headless platform choice and the NumPy 2 patch.

pyrender 0.1.45 still uses ``np.infty`` (removed in NumPy 2), which breaks ``Mesh.bounds``,
``Scene.centroid`` and directional shadows. We restore the alias before pyrender is imported.
It also renders one sample per pixel (see ``_disable_multisampling``) and lets several EGL
renderers share the process's display (see ``_keep_egl_display_alive``). PyOpenGL reads ``PYOPENGL_PLATFORM`` at its first import, so the platform must be chosen before that:
EGL by default (no display needed), OSMesa when asked (``OPENMULTI_GL=osmesa`` or ``platform=``).
"""

from __future__ import annotations

import os
from types import ModuleType

import numpy as np

SUPPORTED_PLATFORMS = ("egl", "osmesa")
_pyrender: ModuleType | None = None


def patch_numpy_for_pyrender() -> None:
    """Give NumPy 2 back the ``np.infty`` alias that pyrender 0.1.45 uses."""
    if not hasattr(np, "infty"):
        np.infty = np.inf  # type: ignore[attr-defined]


def _disable_multisampling(pyrender: ModuleType) -> None:
    """Render with one sample per pixel.

    pyrender draws into a 4x multisampled buffer: colours are averaged at edges, which would mix two
    instance ids into a third one in the segmentation pass, and depth is read from one sample away
    from the pixel centre. A sensor wants exact per-pixel values, so we ask for 0 extra samples.
    """
    from pyrender import renderer  # noqa: PLC0415

    original = renderer.glRenderbufferStorageMultisample
    if getattr(original, "_openmulti_single_sample", False):
        return

    def single_sample(target, _samples, internal_format, width, height):
        return original(target, 0, internal_format, width, height)

    single_sample._openmulti_single_sample = True  # type: ignore[attr-defined]
    renderer.glRenderbufferStorageMultisample = single_sample


def _keep_egl_display_alive() -> None:
    """Let several renderers live in one process.

    All EGL renderers of a process share one display; pyrender's ``delete_context`` terminates it,
    which breaks every other renderer still alive (EGL_BAD_DISPLAY). We destroy only the context.
    """
    from pyrender.platforms import egl  # noqa: PLC0415

    def delete_context(self) -> None:
        from OpenGL.EGL import eglDestroyContext, eglMakeCurrent, EGL_NO_CONTEXT, EGL_NO_SURFACE  # noqa: PLC0415

        if self._egl_display is not None and self._egl_context is not None:
            eglMakeCurrent(self._egl_display, EGL_NO_SURFACE, EGL_NO_SURFACE, EGL_NO_CONTEXT)
            eglDestroyContext(self._egl_display, self._egl_context)
            self._egl_context = None
        self._egl_display = None

    egl.EGLPlatform.delete_context = delete_context


def load_pyrender(platform: str | None = None) -> ModuleType:
    """Import pyrender headless on ``platform`` ("egl" or "osmesa"; default from OPENMULTI_GL or egl).

    Raises:
        ValueError: unknown platform, or a different platform than the one already loaded.
    """
    global _pyrender
    wanted = (platform or os.environ.get("OPENMULTI_GL") or os.environ.get("PYOPENGL_PLATFORM") or "egl").lower()
    if wanted not in SUPPORTED_PLATFORMS:
        raise ValueError(f"unknown GL platform {wanted!r}; choose one of {SUPPORTED_PLATFORMS}")
    if _pyrender is not None:
        current = os.environ.get("PYOPENGL_PLATFORM")
        if current != wanted:
            raise ValueError(
                f"pyrender is already loaded on {current!r}; a process can use only one GL platform "
                f"(asked for {wanted!r})"
            )
        return _pyrender
    os.environ["PYOPENGL_PLATFORM"] = wanted
    patch_numpy_for_pyrender()
    import pyrender  # noqa: PLC0415  (must follow the platform choice and the patch)

    _disable_multisampling(pyrender)
    if wanted == "egl":
        _keep_egl_display_alive()
    _pyrender = pyrender
    return pyrender
