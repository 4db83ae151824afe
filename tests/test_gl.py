import numpy as np
import pytest

from openmulti_env.world.gl import load_pyrender, patch_numpy_for_pyrender


def test_numpy2_patch_makes_pyrender_bounds_work():
    patch_numpy_for_pyrender()
    assert np.infty == np.inf
    pyrender = load_pyrender()
    import trimesh

    mesh = pyrender.Mesh.from_trimesh(trimesh.creation.box(extents=(1.0, 2.0, 3.0)))
    assert np.allclose(mesh.bounds, [[-0.5, -1.0, -1.5], [0.5, 1.0, 1.5]])  # used np.infty before the patch
    scene = pyrender.Scene()
    scene.add(mesh)
    assert np.allclose(scene.centroid, 0.0)


def test_unknown_platform_is_refused():
    with pytest.raises(ValueError, match="unknown GL platform"):
        load_pyrender("directx")
