"""Tests for the parametric furniture library (openmulti_env.world.furniture)."""

from __future__ import annotations

import re

import numpy as np
import pytest

from openmulti_env.world.furniture import (
    CATEGORIES, SMALL_CATEGORIES, FurnitureModel, SupportSurface, build_furniture,
)
from openmulti_env.world.furniture_parts import SCREEN_BLACK, rgba_u8

SEEDS = (0, 1, 2, 3, 7, 11)
PLACEMENTS = {"floor", "wall", "wall_mounted", "on_surface", "ceiling"}


def _models():
    for cat in CATEGORIES:
        for seed in SEEDS:
            yield cat, seed, build_furniture(cat, np.random.default_rng(seed))


MODELS = list(_models())
IDS = [f"{c}-{s}" for c, s, _ in MODELS]


def _all_supports(m: FurnitureModel) -> list[SupportSurface]:
    return list(m.supports) + list(m.soft_supports)


def test_category_counts():
    assert len(CATEGORIES) >= 22
    assert len(SMALL_CATEGORIES) >= 8
    assert len(set(CATEGORIES)) == len(CATEGORIES)
    assert set(SMALL_CATEGORIES) <= set(CATEGORIES)
    for required in ("chair", "table", "desk", "sofa", "bed", "cabinet", "bookshelf", "lamp", "plant",
                     "monitor", "tv", "mug", "bottle", "book", "pillow", "rug", "stool", "door",
                     "window_frame", "picture", "nightstand", "wardrobe", "armchair", "coffee_table",
                     "trash_bin", "box", "keyboard", "laptop", "vase", "table_lamp", "potted_plant"):
        assert required in CATEGORIES


def test_unknown_category_raises():
    with pytest.raises(ValueError) as exc:
        build_furniture("spaceship", np.random.default_rng(0))
    msg = str(exc.value)
    assert "spaceship" in msg and "chair" in msg and "bookshelf" in msg


@pytest.mark.parametrize("cat,seed,m", MODELS, ids=IDS)
def test_basic_fields(cat, seed, m):
    assert isinstance(m, FurnitureModel)
    assert m.category == cat
    assert m.placement in PLACEMENTS
    assert m.is_small == (cat in SMALL_CATEGORIES) == (m.placement == "on_surface")
    assert len(m.color) == 3 and all(0.0 <= c <= 1.0 for c in m.color)
    assert m.color_name and m.material
    assert len(m.parts) >= 1


@pytest.mark.parametrize("cat,seed,m", MODELS, ids=IDS)
def test_geometry_rules(cat, seed, m):
    mesh = m.mesh
    lo, hi = mesh.bounds
    assert lo[2] >= -1e-6 and abs(lo[2]) < 1e-6, "bottom must be at z = 0"
    assert abs(lo[0] + hi[0]) < 1e-3 and abs(lo[1] + hi[1]) < 1e-3, "footprint must be centred"
    np.testing.assert_allclose(m.size_m, mesh.extents, atol=1e-9)
    assert len(mesh.faces) < 3000
    assert len(mesh.faces) == sum(len(p.faces) for p in m.parts)
    for p in m.parts:
        assert p.is_watertight, f"{cat}: part not watertight"
        assert p.bounds[0][2] >= -1e-6
    # realistic overall size
    assert 0.01 <= max(m.size_m) <= 3.5
    if m.is_small:
        assert max(m.size_m) <= 0.8


@pytest.mark.parametrize("cat,seed,m", MODELS, ids=IDS)
def test_face_colors(cat, seed, m):
    fc = np.asarray(m.mesh.visual.face_colors)
    assert fc.shape == (len(m.mesh.faces), 4) and fc.dtype == np.uint8
    if len(m.parts) > 1:
        assert len(np.unique(fc, axis=0)) >= 2, "details should have their own colours"


@pytest.mark.parametrize("cat,seed,m", MODELS, ids=IDS)
def test_caption_mentions_colour_and_material(cat, seed, m):
    cap = m.caption.lower()
    assert m.color_name.lower() in cap
    assert m.material.lower() in cap
    assert not re.search(r"\ba [aeiou]", cap), cap
    assert "{" not in cap and "  " not in cap


@pytest.mark.parametrize("cat", CATEGORIES)
def test_caption_variety(cat):
    skeletons = set()
    for seed in range(40):
        m = build_furniture(cat, np.random.default_rng(1000 + seed))
        s = m.caption.lower().replace(m.color_name.lower(), "<c>").replace(m.material.lower(), "<m>")
        skeletons.add(re.sub(r"\d+", "#", re.sub(r"^an? ", "", s)))
    assert len(skeletons) >= 3, skeletons


@pytest.mark.parametrize("cat", CATEGORIES)
def test_deterministic(cat):
    a = build_furniture(cat, np.random.default_rng(123))
    b = build_furniture(cat, np.random.default_rng(123))
    np.testing.assert_array_equal(a.mesh.vertices, b.mesh.vertices)
    np.testing.assert_array_equal(a.mesh.faces, b.mesh.faces)
    np.testing.assert_array_equal(a.mesh.visual.face_colors, b.mesh.visual.face_colors)
    assert a.caption == b.caption and a.supports == b.supports and a.color == b.color
    c = build_furniture(cat, np.random.default_rng(124))
    assert c.mesh.vertices.shape != a.mesh.vertices.shape or not np.allclose(c.mesh.vertices, a.mesh.vertices)


@pytest.mark.parametrize("cat", ("table", "desk", "coffee_table", "nightstand", "bookshelf", "cabinet", "tv"))
def test_support_categories_have_supports(cat):
    for seed in SEEDS:
        assert build_furniture(cat, np.random.default_rng(seed)).supports


def test_bookshelf_has_support_per_shelf():
    for seed in SEEDS:
        m = build_furniture("bookshelf", np.random.default_rng(seed))
        inner = [s for s in m.supports if s.height_m < m.size_m[2] - 1e-6]
        assert len(inner) >= 2
        hs = sorted(s.height_m for s in inner)
        for a, b, s in zip(hs, hs[1:], sorted(inner, key=lambda s: s.height_m)):
            assert s.clearance_m <= b - a + 1e-9 and s.clearance_m > 0.15


@pytest.mark.parametrize("cat,seed,m", MODELS, ids=IDS)
def test_supports_valid(cat, seed, m):
    sx, sy, _ = m.size_m
    for s in _all_supports(m):
        hx, hy = s.half_extent_xy
        cx, cy = s.center_xy
        assert hx > 0 and hy > 0 and s.clearance_m > 0
        # inside the footprint
        assert -sx / 2 - 1e-9 <= cx - hx and cx + hx <= sx / 2 + 1e-9
        assert -sy / 2 - 1e-9 <= cy - hy and cy + hy <= sy / 2 + 1e-9
        assert 0.0 < s.height_m <= m.size_m[2] + 1e-9
        # resting on top faces of parts that together cover the rectangle (several seat cushions
        # may carry one soft support; gaps of up to 1.5 cm between cushions are tolerated)
        rect_lo = np.array([cx - hx, cy - hy])
        rect_hi = np.array([cx + hx, cy + hy])
        carriers = [p for p in m.parts if abs(p.bounds[1][2] - s.height_m) < 1e-6]
        assert carriers, f"{cat}: no part top at support height {s.height_m:.3f}"
        gx, gy = np.meshgrid(np.linspace(rect_lo[0], rect_hi[0], 9), np.linspace(rect_lo[1], rect_hi[1], 9))
        pts = np.c_[gx.ravel(), gy.ravel()]
        covered = np.zeros(len(pts), bool)
        tol = 1e-9 if s in m.supports else 0.0075
        for p in carriers:
            covered |= np.all((pts >= p.bounds[0][:2] - tol) & (pts <= p.bounds[1][:2] + tol), axis=1)
        assert covered.all(), f"{cat}: support at {s.height_m:.3f} not fully carried"
        # the free box above it is really free
        z0, z1 = s.height_m + 1e-4, s.height_m + s.clearance_m - 1e-4
        for p in m.parts:
            plo, phi = p.bounds
            overlap = (np.all(plo[:2] < rect_hi - 1e-6) and np.all(phi[:2] > rect_lo + 1e-6)
                       and plo[2] < z1 and phi[2] > z0)
            assert not overlap, f"{cat}: part intrudes into the clearance above support at {s.height_m:.3f}"


def test_support_margin_on_table_top():
    m = build_furniture("desk", np.random.default_rng(5))
    top = max(m.supports, key=lambda s: s.height_m)
    assert top.height_m == pytest.approx(m.size_m[2])
    assert top.half_extent_xy[0] == pytest.approx(m.size_m[0] / 2 - 0.03, abs=1e-6)


def test_placements_and_mount_heights():
    expect = {"door": "wall_mounted", "window_frame": "wall_mounted", "picture": "wall_mounted",
              "rug": "floor", "bookshelf": "wall", "wardrobe": "wall", "lamp": "floor", "table_lamp": "on_surface",
              "plant": "floor", "potted_plant": "on_surface", "mug": "on_surface", "monitor": "on_surface"}
    for cat, pl in expect.items():
        assert build_furniture(cat, np.random.default_rng(0)).placement == pl
    for seed in SEEDS:
        rng = np.random.default_rng(seed)
        door = build_furniture("door", rng)
        win = build_furniture("window_frame", rng)
        pic = build_furniture("picture", rng)
        assert door.mount_height_m == 0.0 and 1.9 < door.size_m[2] < 2.3 and 0.8 < door.size_m[0] < 1.2
        assert 0.7 <= win.mount_height_m <= 1.1
        assert 0.9 <= pic.mount_height_m and pic.mount_height_m + pic.size_m[2] / 2 <= 1.7
        for m in (door, win, pic):
            assert m.size_m[1] < 0.25  # thin
            back = min(m.parts, key=lambda p: p.bounds[0][1])
            assert back.bounds[0][1] == pytest.approx(-m.size_m[1] / 2)


def test_rug_is_flat_on_floor():
    for seed in SEEDS:
        m = build_furniture("rug", np.random.default_rng(seed))
        assert m.mesh.bounds[0][2] == pytest.approx(0.0, abs=1e-9)
        assert m.mesh.bounds[1][2] == pytest.approx(0.01, abs=1e-9)


@pytest.mark.parametrize("cat", ("monitor", "tv", "laptop"))
def test_screens_face_plus_y(cat):
    black = rgba_u8(SCREEN_BLACK)
    for seed in SEEDS:
        m = build_furniture(cat, np.random.default_rng(seed))
        fc = np.asarray(m.mesh.visual.face_colors)
        black_faces = np.all(fc == black, axis=1)
        n = m.mesh.face_normals
        cand = np.flatnonzero(black_faces & (n[:, 1] > 0.5))
        assert len(cand), "no screen face looking towards +y"
        f = cand[np.argmax(m.mesh.area_faces[cand])]
        # a ray shot at the screen from in front of it must hit the black display first
        origin = m.mesh.triangles_center[f] + 2.0 * n[f]
        hit = m.mesh.ray.intersects_first(origin[None], -n[f][None])[0]
        assert hit >= 0 and black_faces[hit]


@pytest.mark.parametrize("cat", ("chair", "sofa", "armchair", "bed"))
def test_backrest_is_at_minus_y(cat):
    for seed in SEEDS:
        m = build_furniture(cat, np.random.default_rng(seed))
        v = m.mesh.vertices
        high = v[v[:, 2] > 0.9 * m.size_m[2]]
        assert high[:, 1].mean() < 0.0


def test_beds_have_pillow_area_but_no_pillows():
    for seed in SEEDS:
        m = build_furniture("bed", np.random.default_rng(seed))
        assert m.soft_supports and not m.supports
        assert 0.35 < m.soft_supports[0].height_m < 0.75
        assert len(m.parts) <= 30


def test_size_scale():
    a = build_furniture("bookshelf", np.random.default_rng(9))
    b = build_furniture("bookshelf", np.random.default_rng(9), size_scale=1.5)
    np.testing.assert_allclose(np.array(b.size_m), 1.5 * np.array(a.size_m), rtol=1e-9)
    assert b.mesh.bounds[0][2] == pytest.approx(0.0, abs=1e-9)
    for sa, sb in zip(a.supports, b.supports):
        assert sb.height_m == pytest.approx(1.5 * sa.height_m)
        assert sb.half_extent_xy[0] == pytest.approx(1.5 * sa.half_extent_xy[0])
        assert sb.clearance_m == pytest.approx(1.5 * sa.clearance_m)
