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


def _deterministic_draw_order(pyrender: ModuleType) -> None:
    """Draw meshes and sum lights in an order fixed by the nodes' names.

    pyrender keeps nodes in sets, ordered by memory address, and sorts meshes only by the distance of their
    pose (the identity for every instance here): faces two instances share then win the depth test in a
    different order from one process to the next, and lights add up in another floating-point order (one
    pixel's label and a grey level of RGB changed between two envs of one seed). Sorting ties by name makes
    a seed's frames the same in every process."""
    from pyrender import renderer, scene  # noqa: PLC0415

    if getattr(renderer.Renderer._sorted_mesh_nodes, "_openmulti_by_name", False):
        return
    original = renderer.Renderer._sorted_mesh_nodes

    def by_name(self, scene_):
        nodes = original(self, scene_)  # solid, then transparent, far to near
        cam = scene_.get_pose(scene_.main_camera_node)[:3, 3]

        def key(n):
            return (n.mesh.is_transparent, -round(float(np.linalg.norm(scene_.get_pose(n)[:3, 3] - cam)), 9), n.name or "")
        return sorted(nodes, key=key)

    by_name._openmulti_by_name = True  # type: ignore[attr-defined]
    renderer.Renderer._sorted_mesh_nodes = by_name
    scene.Scene.light_nodes = property(lambda self: sorted(
        self.point_light_nodes | self.spot_light_nodes | self.directional_light_nodes, key=lambda n: n.name or ""))


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
    _deterministic_draw_order(pyrender)
    if wanted == "egl":
        _keep_egl_display_alive()
    _pyrender = pyrender
    return pyrender
