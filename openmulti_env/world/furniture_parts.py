"""Primitive helpers, colour palette and caption utilities for :mod:`furniture`.

Every helper returns a closed (watertight) ``trimesh.Trimesh`` whose
``visual.face_colors`` are already set, so parts can simply be collected in a
list and concatenated.  Conventions (shared with :mod:`furniture`):

* metres, z up, local object frame, front of the object is +y;
* position arguments ``x, y`` are the centre of the part's footprint and
  ``z`` is the *bottom* of the part (except :func:`sphere`, :func:`torus`,
  which take their centre);
* colours are rgb tuples of floats in [0, 1].
"""

from __future__ import annotations

import re
from typing import Sequence

import numpy as np
import trimesh
from trimesh import creation

RGB = tuple[float, float, float]

SECTIONS = 16  # default number of sections for round primitives


# --------------------------------------------------------------------------- colours

PALETTE: dict[str, RGB] = {
    "white": (0.93, 0.93, 0.92),
    "off-white": (0.90, 0.88, 0.82),
    "cream": (0.94, 0.89, 0.76),
    "beige": (0.84, 0.76, 0.62),
    "light grey": (0.76, 0.76, 0.77),
    "grey": (0.52, 0.52, 0.54),
    "dark grey": (0.28, 0.28, 0.30),
    "charcoal": (0.18, 0.18, 0.20),
    "black": (0.07, 0.07, 0.08),
    "red": (0.78, 0.12, 0.12),
    "dark red": (0.48, 0.08, 0.10),
    "orange": (0.93, 0.50, 0.13),
    "yellow": (0.95, 0.82, 0.18),
    "mustard yellow": (0.80, 0.62, 0.13),
    "green": (0.20, 0.58, 0.25),
    "olive green": (0.45, 0.48, 0.20),
    "dark green": (0.10, 0.34, 0.18),
    "sage green": (0.60, 0.70, 0.55),
    "teal": (0.05, 0.50, 0.50),
    "blue": (0.15, 0.35, 0.78),
    "navy blue": (0.08, 0.12, 0.36),
    "light blue": (0.60, 0.78, 0.92),
    "purple": (0.45, 0.22, 0.60),
    "pink": (0.93, 0.60, 0.70),
    "terracotta": (0.78, 0.40, 0.25),
    "brown": (0.45, 0.28, 0.15),
    "tan": (0.78, 0.64, 0.46),
    "walnut brown": (0.36, 0.23, 0.13),
    "dark brown": (0.24, 0.15, 0.09),
    "oak brown": (0.62, 0.45, 0.27),
    "light oak": (0.80, 0.66, 0.46),
    "honey brown": (0.72, 0.50, 0.25),
    "silver": (0.75, 0.76, 0.78),
    "gold": (0.83, 0.68, 0.21),
    "clear": (0.82, 0.90, 0.92),
    "amber": (0.66, 0.38, 0.08),
}

# plausible colour names per material (categories may override)
MATERIAL_COLORS: dict[str, tuple[str, ...]] = {
    "wooden": ("walnut brown", "oak brown", "light oak", "dark brown", "honey brown", "white", "black"),
    "metal": ("black", "silver", "grey", "dark grey", "white"),
    "fabric": ("grey", "light grey", "dark grey", "beige", "blue", "navy blue", "green", "dark green",
               "olive green", "mustard yellow", "red", "teal", "cream", "pink", "charcoal", "sage green"),
    "velvet": ("navy blue", "dark green", "mustard yellow", "pink", "teal", "dark red", "purple", "grey"),
    "cotton": ("white", "cream", "light grey", "light blue", "beige", "pink", "sage green", "yellow"),
    "linen": ("beige", "off-white", "light grey", "sage green", "tan"),
    "leather": ("black", "brown", "dark brown", "tan", "cream"),
    "plastic": ("white", "black", "red", "blue", "green", "yellow", "grey", "orange", "pink", "light blue"),
    "ceramic": ("white", "off-white", "blue", "terracotta", "black", "green", "yellow", "grey", "cream",
                "teal", "red", "pink", "sage green"),
    "glass": ("clear", "green", "amber", "blue", "light blue"),
    "marble": ("white", "black", "grey"),
    "wool": ("beige", "cream", "grey", "red", "navy blue", "dark red", "teal", "mustard yellow", "charcoal"),
    "jute": ("beige", "tan"),
    "cardboard": ("brown", "tan"),
    "paper": ("red", "blue", "green", "yellow", "black", "white", "orange", "purple", "navy blue",
              "dark red", "dark green", "teal", "brown", "grey", "pink"),
}

FOLIAGE = ((0.18, 0.45, 0.16), (0.25, 0.55, 0.20), (0.12, 0.36, 0.14), (0.35, 0.55, 0.22))
SCREEN_BLACK: RGB = (0.03, 0.03, 0.04)


def jitter(rgb: Sequence[float], rng: np.random.Generator, amount: float = 0.03) -> RGB:
    """Small per-instance colour variation (same for all channels plus a tiny hue shift)."""
    base = np.asarray(rgb, dtype=float)
    out = base * (1.0 + rng.uniform(-amount, amount)) + rng.uniform(-amount, amount, 3) * 0.5
    return tuple(float(v) for v in np.clip(out, 0.0, 1.0))


def shade(rgb: Sequence[float], factor: float) -> RGB:
    """factor < 1 darkens; factor > 1 blends towards white (factor 2 = white)."""
    c = np.asarray(rgb, dtype=float)
    if factor <= 1.0:
        c = c * factor
    else:
        c = c + (1.0 - c) * min(factor - 1.0, 1.0)
    return tuple(float(v) for v in np.clip(c, 0.0, 1.0))


def pick_color(rng: np.random.Generator, names: Sequence[str], amount: float = 0.03) -> tuple[str, RGB]:
    """Choose a named colour and jitter it; returns (name, rgb)."""
    name = str(names[int(rng.integers(len(names)))])
    return name, jitter(PALETTE[name], rng, amount)


def material_color(rng: np.random.Generator, material: str, amount: float = 0.03) -> tuple[str, RGB]:
    return pick_color(rng, MATERIAL_COLORS[material], amount)


def choice(rng: np.random.Generator, options: Sequence, p: Sequence[float] | None = None):
    """rng.choice that keeps python objects (str, tuples) intact."""
    if p is not None:
        p = np.asarray(p, dtype=float)
        p = p / p.sum()
    return options[int(rng.choice(len(options), p=p))]


def rgba_u8(rgb: Sequence[float], alpha: float = 1.0) -> np.ndarray:
    c = np.clip(np.r_[np.asarray(rgb, dtype=float)[:3], alpha], 0.0, 1.0)
    return np.round(c * 255.0).astype(np.uint8)


# --------------------------------------------------------------------------- captions

_AN = re.compile(r"\b([Aa]) (?=(?:[aeiouAEIOU]|8|11|18)\w*)")


def fix_articles(text: str) -> str:
    """'a orange mug' -> 'an orange mug'."""
    return _AN.sub(lambda m: ("An " if m.group(1) == "A" else "an "), text)


def caption(rng: np.random.Generator, templates: Sequence[str], **fields) -> str:
    """Pick one template at random and fill it.  Templates use ``{c}`` (colour name) and
    ``{m}`` (material word) and any extra named fields."""
    t = templates[int(rng.integers(len(templates)))]
    text = " ".join(t.format(**fields).split())
    return fix_articles(text)


# --------------------------------------------------------------------------- primitives

def _paint(mesh: trimesh.Trimesh, rgb: Sequence[float]) -> trimesh.Trimesh:
    mesh.visual.face_colors = np.tile(rgba_u8(rgb), (len(mesh.faces), 1))
    return mesh


def box(sx: float, sy: float, sz: float, x: float = 0.0, y: float = 0.0, z: float = 0.0,
        color: Sequence[float] = (0.5, 0.5, 0.5)) -> trimesh.Trimesh:
    """Axis-aligned box of size (sx, sy, sz); footprint centred at (x, y), bottom at z."""
    m = creation.box(extents=(sx, sy, sz))
    m.apply_translation((x, y, z + sz / 2.0))
    return _paint(m, color)


def box_between(lo: Sequence[float], hi: Sequence[float], color: Sequence[float]) -> trimesh.Trimesh:
    """Axis-aligned box from corner ``lo`` to corner ``hi``."""
    lo = np.asarray(lo, float)
    hi = np.asarray(hi, float)
    s = hi - lo
    c = (lo + hi) / 2.0
    return box(s[0], s[1], s[2], c[0], c[1], lo[2], color)


def cylinder(r: float, h: float, x: float = 0.0, y: float = 0.0, z: float = 0.0,
             color: Sequence[float] = (0.5, 0.5, 0.5), sections: int = SECTIONS) -> trimesh.Trimesh:
    """Vertical cylinder, footprint centre (x, y), bottom at z."""
    m = creation.cylinder(radius=r, height=h, sections=sections)
    m.apply_translation((x, y, z + h / 2.0))
    return _paint(m, color)


def rod(p0: Sequence[float], p1: Sequence[float], r: float, color: Sequence[float],
        sections: int = 12) -> trimesh.Trimesh:
    """Cylinder between two points (slanted legs, poles, handles)."""
    m = creation.cylinder(radius=r, segment=np.array([p0, p1], dtype=float), sections=sections)
    return _paint(m, color)


def hbar(length: float, r: float, x: float, y: float, zc: float, color: Sequence[float],
         axis: str = "x", sections: int = 10) -> trimesh.Trimesh:
    """Horizontal round bar centred at (x, y, zc) along ``axis`` ('x' or 'y')."""
    d = np.array([length / 2.0, 0.0, 0.0]) if axis == "x" else np.array([0.0, length / 2.0, 0.0])
    c = np.array([x, y, zc])
    return rod(c - d, c + d, r, color, sections)


def lathe(profile: Sequence[Sequence[float]], x: float = 0.0, y: float = 0.0, z: float = 0.0,
          color: Sequence[float] = (0.5, 0.5, 0.5), sections: int = SECTIONS) -> trimesh.Trimesh:
    """Solid of revolution around the vertical axis.  ``profile`` is a list of (radius, height)
    points; it is closed onto the axis automatically (first/last points get radius 0), which makes
    the result watertight.  A profile that goes up the outside and back down the inside gives a
    hollow vessel (mug, vase, bin)."""
    pts = [tuple(map(float, p)) for p in profile]
    if pts[0][0] != 0.0:
        pts.insert(0, (0.0, pts[0][1]))
    if pts[-1][0] != 0.0:
        pts.append((0.0, pts[-1][1]))
    m = creation.revolve(np.array(pts), sections=sections)
    m.apply_translation((x, y, z))
    return _paint(m, color)


def frustum(r_bottom: float, r_top: float, h: float, x: float = 0.0, y: float = 0.0, z: float = 0.0,
            color: Sequence[float] = (0.5, 0.5, 0.5), sections: int = SECTIONS) -> trimesh.Trimesh:
    """Truncated cone (lamp shade, pot, bin)."""
    return lathe([(0, 0), (r_bottom, 0), (r_top, h), (0, h)], x, y, z, color, sections)


def sphere(r: float, x: float, y: float, zc: float, color: Sequence[float], subdivisions: int = 1,
           scale: Sequence[float] = (1.0, 1.0, 1.0)) -> trimesh.Trimesh:
    """Icosphere (optionally scaled to an ellipsoid) centred at (x, y, zc)."""
    m = creation.icosphere(subdivisions=subdivisions, radius=r)
    m.apply_scale(np.asarray(scale, dtype=float))
    m.apply_translation((x, y, zc))
    return _paint(m, color)


def rounded_box(sx: float, sy: float, sz: float, x: float = 0.0, y: float = 0.0, z: float = 0.0,
                color: Sequence[float] = (0.5, 0.5, 0.5), squareness: float = 0.35,
                puff: float = 0.0, subdivisions: int = 2) -> trimesh.Trimesh:
    """Soft box ("squircle" ellipsoid): an icosphere whose vertices are pushed towards the cube
    (exponent ``squareness`` < 1), scaled to (sx, sy, sz); ``puff`` > 0 thins the edges relative
    to the middle (pillows).  Footprint centre (x, y), bottom at z."""
    m = creation.icosphere(subdivisions=subdivisions, radius=1.0)
    v = m.vertices.copy()
    v = np.sign(v) * np.abs(v) ** squareness
    if puff > 0.0:
        edge = np.maximum(np.abs(v[:, 0]), np.abs(v[:, 1]))
        v[:, 2] *= 1.0 - puff * edge ** 4
    m.vertices = v
    lo, hi = m.bounds
    m.apply_translation(-(lo + hi) / 2.0)
    m.apply_scale(np.array([sx, sy, sz]) / np.maximum(hi - lo, 1e-9))
    m.apply_translation((x, y, z + sz / 2.0))
    return _paint(m, color)


def capsule(r: float, h: float, x: float = 0.0, y: float = 0.0, z: float = 0.0,
            color: Sequence[float] = (0.5, 0.5, 0.5)) -> trimesh.Trimesh:
    """Vertical capsule of radius r and total height h; footprint centre (x, y), bottom at z."""
    m = creation.capsule(height=max(h - 2 * r, 1e-3), radius=r, count=[10, 6])
    m.apply_translation((x, y, z + h / 2.0))
    return _paint(m, color)


def torus(major_r: float, minor_r: float, center: Sequence[float], color: Sequence[float],
          axis: str = "z", major_sections: int = 16, minor_sections: int = 8) -> trimesh.Trimesh:
    """Torus centred at ``center`` whose symmetry axis is 'x', 'y' or 'z'."""
    m = creation.torus(major_r, minor_r, major_sections=major_sections, minor_sections=minor_sections)
    if axis == "y":
        m.apply_transform(trimesh.transformations.rotation_matrix(np.pi / 2, (1, 0, 0)))
    elif axis == "x":
        m.apply_transform(trimesh.transformations.rotation_matrix(np.pi / 2, (0, 1, 0)))
    m.apply_translation(center)
    return _paint(m, color)


def rotate_x(mesh: trimesh.Trimesh, angle: float, pivot: Sequence[float]) -> trimesh.Trimesh:
    """Rotate in place about an x-parallel axis through ``pivot`` (right-handed: +y -> +z)."""
    mesh.apply_transform(trimesh.transformations.rotation_matrix(angle, (1, 0, 0), pivot))
    return mesh


def concat(parts: Sequence[trimesh.Trimesh]) -> trimesh.Trimesh:
    """Concatenate parts keeping per-face colours in part order."""
    colors = np.vstack([np.asarray(p.visual.face_colors, dtype=np.uint8) for p in parts])
    mesh = trimesh.util.concatenate(list(parts))
    mesh.visual.face_colors = colors
    return mesh
