"""The env's ``rgb_array`` picture: every agent's local map side by side, then the team panel with the
paths walked so far and the links used this step (parameters: white, rays: cyan, both: yellow)."""

from __future__ import annotations

import numpy as np
from scipy.ndimage import grey_dilation
from skimage.draw import line

AGENT_COLOURS = np.array([[230, 25, 75], [60, 180, 75], [0, 130, 200], [245, 130, 48], [145, 30, 180],
                          [70, 240, 240], [240, 50, 230], [210, 245, 60]], np.uint8)
PARAMS_COLOUR, RAYS_COLOUR, BOTH_COLOUR = (255, 255, 255), (0, 220, 255), (255, 225, 25)
TILE_PX = 192


def agent_tile(observation: np.ndarray, colour: np.ndarray) -> np.ndarray:
    """(TILE_PX, TILE_PX, 3) picture of one ``map`` observation: the height of its own map in grey (brighter
    where its fields decide more of the column), observed-but-unmapped cells dark blue, received instances
    green, own path in the agent's colour, peers' last known positions yellow."""
    height, decided, observed, received, path, peers = (observation[..., k].astype(np.float32) / 255
                                                         for k in range(6))
    rgb = np.zeros(observation.shape[:2] + (3,), np.float32)
    rgb += (observed > 0)[..., None] * np.array([0.05, 0.08, 0.25])
    mapped = height > 0
    shade = (0.25 + 0.5 * height + 0.25 * decided) * mapped
    rgb = np.where(mapped[..., None], shade[..., None] * np.array([1.0, 1.0, 1.0]), rgb)
    rgb[..., 1] = np.maximum(rgb[..., 1], 0.45 * received)
    on_path = path > 0
    rgb[on_path] = colour / 255 * (0.5 + 0.5 * path[on_path, None])
    rgb[peers > 0] = np.array([1.0, 0.9, 0.1])
    return _upscale(np.round(rgb * 255).astype(np.uint8), TILE_PX)


def team_panel(floor: np.ndarray, paths: list[np.ndarray], positions: list[np.ndarray | None],
               send: np.ndarray, rays: np.ndarray) -> np.ndarray:
    """(TILE_PX, TILE_PX, 3) panel: the observable floor plan (grey), each agent's path (cells, in grid
    units, in its colour) and a line per link used this step between the agents' current cells."""
    size = floor.shape[0]
    scale = TILE_PX / size
    floor = grey_dilation(floor, size=3)  # the probes' cells, thickened for the eye
    img = _upscale(np.repeat((floor[..., None] > 0) * np.uint8(60), 3, axis=2), TILE_PX)
    for a, cells in enumerate(paths):
        for r, c in cells:
            r0, c0 = int(r * scale), int(c * scale)
            img[r0:r0 + max(int(scale), 1), c0:c0 + max(int(scale), 1)] = AGENT_COLOURS[a % len(AGENT_COLOURS)]
    n = len(positions)
    for i in range(n):
        for j in range(n):
            if i == j or not (send[i, j] or rays[i, j]) or positions[i] is None or positions[j] is None:
                continue
            colour = BOTH_COLOUR if send[i, j] and rays[i, j] else PARAMS_COLOUR if send[i, j] else RAYS_COLOUR
            (ri, ci), (rj, cj) = (np.clip((np.asarray(p) + 0.5) * scale, 0, TILE_PX - 1).astype(int)
                                  for p in (positions[i], positions[j]))
            rr, cc = line(ri, ci, rj, cj)
            img[rr, cc] = colour
    return img


def compose(tiles: list[np.ndarray], panel: np.ndarray, gap: int = 4) -> np.ndarray:
    """Tiles then the panel, left to right, on a dark background: (TILE_PX, W, 3) uint8."""
    parts = []
    for tile in [*tiles, panel]:
        parts.extend([tile, np.full((TILE_PX, gap, 3), 20, np.uint8)])
    return np.ascontiguousarray(np.concatenate(parts[:-1], axis=1)[::-1])  # +y up in the picture


def _upscale(img: np.ndarray, px: int) -> np.ndarray:
    k = max(px // img.shape[0], 1)
    big = np.kron(img, np.ones((k, k, 1), np.uint8))
    out = np.zeros((px, px, 3), np.uint8)
    h, w = min(px, big.shape[0]), min(px, big.shape[1])
    out[:h, :w] = big[:h, :w]
    return out


def team_picture(maps: list[np.ndarray], grid, floor: np.ndarray, walked: list[np.ndarray],
                 links: tuple[np.ndarray, np.ndarray]) -> np.ndarray:
    """The env's ``render``: each agent's map tile, then the team panel with the paths walked so far
    (``walked[i]``: agent i's (F, 4, 4) poses read), where each agent stands, and this round's links."""
    tiles = [agent_tile(m, AGENT_COLOURS[i % len(AGENT_COLOURS)]) for i, m in enumerate(maps)]
    paths, positions = [], []
    for poses in walked:
        rows, cols, inside = grid.cells(poses[:, :3, 3])
        paths.append(list(zip(rows[inside], cols[inside])))
        positions.append((rows[-1], cols[-1]) if len(poses) and inside[-1] else None)
    return compose(tiles, team_panel(floor, paths, positions, *links))
