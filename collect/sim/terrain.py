"""Heightfield terrain grid for the batched MuJoCo quadruped sim (legged_gym style).

The grid is made of square tiles: one column of tiles per terrain type (repeated
``columns_per_type`` times, type-major) and one row per difficulty level, surrounded by a
flat border. Difficulty of level ``L`` is ``d = L / num_levels`` (legged_gym: row / num_rows).

Conventions (world frame, metres):

- ``heights[iy, ix]`` is the ground height at ``x = x0 + ix * horizontal_scale``,
  ``y = y0 + iy * horizontal_scale``: the row index is y, the column index is x.
- ``x0 = y0 = -border``: tile ``(column c, level L)`` covers
  ``x in [c * tile_size, (c + 1) * tile_size]``, ``y in [L * tile_size, (L + 1) * tile_size]``.
- Every tile's outer edge is at z = 0 (the border too); its centre platform height is known
  (``Terrain.center_heights``) and ``tile_center`` returns the ground there.
- All heights are multiples of ``vertical_scale``.

See docs/terrains.md for the per-type parameterization and pictures.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass

import numpy as np

TERRAIN_TYPES: tuple[str, ...] = (
    "flat", "smooth_slope", "rough_slope", "stairs_up", "stairs_down", "discrete",
)

# legged_gym's terrain proportions (its LeggedRobotCfg.terrain), for sample_initial(type_weights=...).
LEGGED_GYM_TYPE_WEIGHTS: dict[str, float] = {
    "smooth_slope": 0.1, "rough_slope": 0.1, "stairs_up": 0.35, "stairs_down": 0.25,
    "discrete": 0.2,
}

# legged_gym parameterization (its utils/terrain.py); d = level / num_levels.
SLOPE_PER_DIFFICULTY = 0.4          # pyramid slope gradient = 0.4 d
ROUGH_NOISE = 0.05                  # uniform noise in [-0.05, 0.05] m on rough slopes
ROUGH_NOISE_STEP = 0.005            # noise values are multiples of this
ROUGH_NOISE_SPACING = 0.2           # noise drawn on a 0.2 m grid, bilinearly upsampled
STAIR_BASE, STAIR_PER_DIFFICULTY = 0.05, 0.18   # step height = 0.05 + 0.18 d
STAIR_TREAD = 0.31                  # tread depth (m)
DISCRETE_BASE, DISCRETE_PER_DIFFICULTY = 0.05, 0.2   # obstacle height = 0.05 + 0.2 d
DISCRETE_NUM_RECTS = 20
DISCRETE_SIZE_RANGE = (1.0, 2.0)    # rectangle side lengths (m)


def _as_int_ratio(value: float, scale: float, what: str) -> int:
    """``value / scale`` as an int, or ValueError naming ``what`` if it is not integral."""
    n = round(value / scale)
    if n <= 0 or not math.isclose(n * scale, value, rel_tol=1e-9, abs_tol=1e-9):
        raise ValueError(f"{what}={value} must be a positive multiple of horizontal_scale={scale}")
    return n


@dataclass
class TerrainConfig:
    """Terrain grid configuration (draccus-compatible; validated on construction).

    Args:
        types: terrain types, one tile column each (in this order); names from TERRAIN_TYPES.
        num_levels: difficulty levels (tile rows); level L has difficulty L / num_levels.
        columns_per_type: how many tile columns each type gets (type-major order).
        tile_size: tile side length (m); a multiple of horizontal_scale, even in samples.
        horizontal_scale: heightfield sample spacing (m).
        vertical_scale: height quantization (m).
        border: flat border (z = 0) around the whole grid (m); multiple of horizontal_scale.
        curriculum: start robots at levels <= max_init_level and move them up/down
            (update_levels); if False, initial levels are uniform over all levels.
        max_init_level: initial levels are sampled in [0, max_init_level] with curriculum
            (capped at num_levels - 1).
        platform_size: side of the flat spawn platform at each tile centre (m).
        base_depth: thickness of MuJoCo's solid box under the lowest point (m).
    """

    types: tuple[str, ...] = TERRAIN_TYPES
    num_levels: int = 10
    columns_per_type: int = 1
    tile_size: float = 8.0
    horizontal_scale: float = 0.1
    vertical_scale: float = 0.005
    border: float = 10.0
    curriculum: bool = True
    max_init_level: int = 5
    platform_size: float = 3.0
    base_depth: float = 1.0

    def __post_init__(self) -> None:
        self.types = tuple(self.types)
        if not self.types:
            raise ValueError("types must name at least one terrain type")
        for name in self.types:
            if name not in TILE_GENERATORS:
                raise ValueError(f"unknown terrain type {name!r}; known: {sorted(TILE_GENERATORS)}")
        if len(set(self.types)) != len(self.types):
            raise ValueError(f"types has duplicates: {self.types}; use columns_per_type instead")
        for field in ("num_levels", "columns_per_type"):
            if int(getattr(self, field)) < 1:
                raise ValueError(f"{field}={getattr(self, field)} must be >= 1")
        for field in ("horizontal_scale", "vertical_scale", "tile_size", "base_depth"):
            if not float(getattr(self, field)) > 0:
                raise ValueError(f"{field}={getattr(self, field)} must be > 0")
        if self.tile_samples % 2:
            raise ValueError(f"tile_size={self.tile_size} must be an even number of samples")
        if self.border != 0:
            _as_int_ratio(self.border, self.horizontal_scale, "border")
        if not 0 <= self.platform_size <= self.tile_size:
            raise ValueError(f"platform_size={self.platform_size} must be in [0, tile_size]")
        if self.max_init_level < 0:
            raise ValueError(f"max_init_level={self.max_init_level} must be >= 0")

    @property
    def tile_samples(self) -> int:
        """Samples per tile side."""
        return _as_int_ratio(self.tile_size, self.horizontal_scale, "tile_size")

    @property
    def border_samples(self) -> int:
        """Samples in the border on each side."""
        return round(self.border / self.horizontal_scale)


# ----------------------------------------------------------------------------- tiles
# A tile generator maps local coordinates u (x, shape (1, n)) and v (y, shape (n, 1)),
# metres from the tile centre, plus difficulty d to unquantized heights (n, n).
TileFn = Callable[[np.ndarray, np.ndarray, float, TerrainConfig, np.random.Generator], np.ndarray]


def _edge_distance(u: np.ndarray, v: np.ndarray, cfg: TerrainConfig) -> np.ndarray:
    """Distance from the tile's outer edge towards the centre, capped at the platform."""
    dist = cfg.tile_size / 2 - np.maximum(np.abs(u), np.abs(v))
    return np.minimum(dist, (cfg.tile_size - cfg.platform_size) / 2)


def _flat(u, v, d, cfg, rng) -> np.ndarray:
    return np.zeros(np.broadcast_shapes(u.shape, v.shape))


def _smooth_slope(u, v, d, cfg, rng) -> np.ndarray:
    """Square pyramid, summit platform at the centre: walking outwards goes downhill."""
    return SLOPE_PER_DIFFICULTY * d * _edge_distance(u, v, cfg)


def _upsample_noise(coarse: np.ndarray, coarse_xy: np.ndarray, fine_xy: np.ndarray) -> np.ndarray:
    """Bilinear upsampling of a square coarse grid (m, m) to (n, n) as W @ coarse @ W.T."""
    eye = np.eye(len(coarse_xy))
    weights = np.stack([np.interp(fine_xy, coarse_xy, row) for row in eye], axis=1)  # (n, m)
    return weights @ coarse @ weights.T


def _rough_slope(u, v, d, cfg, rng) -> np.ndarray:
    """The smooth pyramid plus uniform noise of +-5 cm drawn on a 0.2 m grid."""
    fine = u.ravel()
    coarse_xy = np.arange(fine[0], fine[-1] + ROUGH_NOISE_SPACING, ROUGH_NOISE_SPACING)
    n_levels = round(2 * ROUGH_NOISE / ROUGH_NOISE_STEP)
    coarse = (rng.integers(0, n_levels + 1, size=(len(coarse_xy),) * 2) * ROUGH_NOISE_STEP
              - ROUGH_NOISE)
    return _smooth_slope(u, v, d, cfg, rng) + _upsample_noise(coarse, coarse_xy, fine)


def stair_step_height(d: float, vertical_scale: float) -> float:
    """Stair riser height at difficulty d, quantized to the vertical grid."""
    return round((STAIR_BASE + STAIR_PER_DIFFICULTY * d) / vertical_scale) * vertical_scale


def _stair_count(u, v, cfg) -> np.ndarray:
    """Number of risers between the tile edge and each point (capped at the platform)."""
    return np.floor(_edge_distance(u, v, cfg) / STAIR_TREAD + 1e-9)


def _stairs_up(u, v, d, cfg, rng) -> np.ndarray:
    """Pyramid stairs with the platform as a pit: walking outwards climbs up."""
    return -stair_step_height(d, cfg.vertical_scale) * _stair_count(u, v, cfg)


def _stairs_down(u, v, d, cfg, rng) -> np.ndarray:
    """Pyramid stairs with the platform on top: walking outwards goes down."""
    return stair_step_height(d, cfg.vertical_scale) * _stair_count(u, v, cfg)


def _discrete(u, v, d, cfg, rng) -> np.ndarray:
    """20 random rectangles of 1-2 m sides raised/lowered by +-h or +-h/2; flat platform."""
    n, hs = cfg.tile_samples, cfg.horizontal_scale
    h = DISCRETE_BASE + DISCRETE_PER_DIFFICULTY * d
    heights = np.zeros((n, n))
    for _ in range(DISCRETE_NUM_RECTS):
        w, l = np.minimum(np.round(rng.uniform(*DISCRETE_SIZE_RANGE, size=2) / hs), n).astype(int)
        ix, iy = rng.integers(0, n - w + 1), rng.integers(0, n - l + 1)
        heights[iy:iy + l, ix:ix + w] = rng.choice([-h, -h / 2, h / 2, h])
    on_platform = np.maximum(np.abs(u), np.abs(v)) <= cfg.platform_size / 2 + 1e-9
    heights[on_platform] = 0.0
    return heights


TILE_GENERATORS: dict[str, TileFn] = {
    "flat": _flat,
    "smooth_slope": _smooth_slope,
    "rough_slope": _rough_slope,
    "stairs_up": _stairs_up,
    "stairs_down": _stairs_down,
    "discrete": _discrete,
}
# Stable per-type seed salt, so a tile's randomness doesn't depend on cfg.types order.
_TYPE_SALT = {name: i for i, name in enumerate(TILE_GENERATORS)}


# ----------------------------------------------------------------------------- grid
def _cell_table(h: np.ndarray) -> np.ndarray:
    """(nrow * ncol, 4) per cell [h00, h01 - h00, h10, h11 - h10] (0 = lower-left corner),
    so that height_at needs a single gather of 16-byte rows per point."""
    cells = np.zeros(h.shape + (4,), dtype=np.float32)
    cells[:-1, :-1, 0] = h[:-1, :-1]
    cells[:-1, :-1, 1] = h[:-1, 1:] - h[:-1, :-1]
    cells[:-1, :-1, 2] = h[1:, :-1]
    cells[:-1, :-1, 3] = h[1:, 1:] - h[1:, :-1]
    return cells.reshape(-1, 4)


class Terrain:
    """A deterministic terrain grid built from a config and a seed.

    Args:
        cfg: the grid configuration.
        seed: seeds the random tiles (rough slope noise, discrete obstacles). Each tile
            draws from its own stream keyed by (seed, type name, level, repeat index),
            so it does not depend on the order of cfg.types. Must be >= 0.

    Attributes:
        heights: (nrow, ncol) float32 ground height (m); row index = y, column index = x.
        x0, y0: world coordinates of sample [0, 0] (= -border).
        center_heights: (num_levels, num_columns) ground height at each tile centre.
    """

    def __init__(self, cfg: TerrainConfig, seed: int = 0) -> None:
        if int(seed) < 0:
            raise ValueError(f"seed={seed} must be >= 0")
        self.cfg = cfg
        self.seed = int(seed)
        n, b = cfg.tile_samples, cfg.border_samples
        self.num_columns = len(cfg.types) * cfg.columns_per_type
        self.x0 = self.y0 = -b * cfg.horizontal_scale
        heights = np.zeros((cfg.num_levels * n + 2 * b + 1, self.num_columns * n + 2 * b + 1))
        local = (np.arange(n) - n // 2) * cfg.horizontal_scale   # centre sample at u = 0
        u, v = local[None, :], local[:, None]
        for col in range(self.num_columns):
            name = cfg.types[col // cfg.columns_per_type]
            for level in range(cfg.num_levels):
                rng = np.random.default_rng(
                    [self.seed, _TYPE_SALT[name], level, col % cfg.columns_per_type])
                tile = TILE_GENERATORS[name](u, v, level / cfg.num_levels, cfg, rng)
                heights[b + level * n: b + (level + 1) * n, b + col * n: b + (col + 1) * n] = tile
        q = cfg.vertical_scale
        self.heights = (np.round(heights / q) * q).astype(np.float32)
        self._cells = _cell_table(self.heights)
        centres = b + np.arange(cfg.num_levels)[:, None] * n + n // 2, \
            b + np.arange(self.num_columns)[None, :] * n + n // 2
        self.center_heights = self.heights[centres[0], centres[1]]

    # -- indexing ------------------------------------------------------------------
    def level_type_index(self, name: str) -> int:
        """Index of terrain type ``name`` in ``cfg.types`` (ValueError if absent).

        Args:
            name: a terrain type name.
        """
        if name not in self.cfg.types:
            raise ValueError(f"terrain type {name!r} is not in this grid's types {self.cfg.types}")
        return self.cfg.types.index(name)

    def _check_tiles(self, type_idx: np.ndarray, level: np.ndarray) -> None:
        for what, arr, hi in (("type_idx", type_idx, len(self.cfg.types)),
                              ("level", level, self.cfg.num_levels)):
            bad = arr[(arr < 0) | (arr >= hi)]
            if bad.size:
                raise ValueError(f"{what} {int(bad[0])} out of range [0, {hi})")

    def tile_center(self, type_idx: np.ndarray, level: np.ndarray,
                    column: np.ndarray | int | None = None,
                    rng: np.random.Generator | None = None) -> np.ndarray:
        """World xyz of tile centres on the ground (the spawn platform).

        Args:
            type_idx: (N,) indices into cfg.types.
            level: (N,) levels in [0, num_levels).
            column: which repeat of the type (0..columns_per_type-1); default 0, or random
                per entry if ``rng`` is given.
            rng: draws the repeat column when ``column`` is None.

        Returns:
            (N, 3) float64 positions.
        """
        type_idx = np.asarray(type_idx, dtype=np.int64)
        level = np.asarray(level, dtype=np.int64)
        type_idx, level = np.broadcast_arrays(type_idx, level)
        self._check_tiles(type_idx, level)
        cpt = self.cfg.columns_per_type
        if column is None:
            column = rng.integers(0, cpt, size=type_idx.shape) if rng is not None else 0
        column = np.broadcast_to(np.asarray(column, dtype=np.int64), type_idx.shape)
        bad = column[(column < 0) | (column >= cpt)]
        if bad.size:
            raise ValueError(f"column {int(bad[0])} out of range [0, columns_per_type={cpt})")
        col = type_idx * cpt + column
        t = self.cfg.tile_size
        return np.stack([(col + 0.5) * t, (level + 0.5) * t,
                         self.center_heights[level, col].astype(np.float64)], axis=-1)

    def tile_of(self, xy: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """(type_idx, level) of the tile under each point; both -1 on the border.

        Args:
            xy: (..., 2) world positions.
        """
        xy = np.asarray(xy, dtype=np.float64)
        col = np.floor(xy[..., 0] / self.cfg.tile_size).astype(np.int64)
        row = np.floor(xy[..., 1] / self.cfg.tile_size).astype(np.int64)
        inside = (col >= 0) & (col < self.num_columns) & (row >= 0) & (row < self.cfg.num_levels)
        type_idx = np.where(inside, col // self.cfg.columns_per_type, -1)
        return type_idx, np.where(inside, row, -1)

    # -- heights -------------------------------------------------------------------
    def height_at(self, xy: np.ndarray) -> np.ndarray:
        """Bilinearly interpolated ground height; points outside the grid are clamped to it.

        Args:
            xy: (..., 2) world positions.

        Returns:
            (...) float32 heights (m).
        """
        xy = np.asarray(xy, dtype=np.float32)
        if xy.ndim == 0 or xy.shape[-1] != 2:
            raise ValueError(f"xy must have shape (..., 2), got {xy.shape}")
        nrow, ncol = self.heights.shape
        inv = np.float32(1.0 / self.cfg.horizontal_scale)
        fx = np.subtract(xy[..., 0], np.float32(self.x0), out=np.empty(xy.shape[:-1], np.float32))
        fy = np.subtract(xy[..., 1], np.float32(self.y0), out=np.empty(xy.shape[:-1], np.float32))
        fx *= inv
        fy *= inv
        for f, hi in ((fx, ncol - 1), (fy, nrow - 1)):           # clamp (faster than np.clip)
            np.maximum(f, 0, out=f)
            np.minimum(f, hi, out=f)
        ix = np.minimum(fx.astype(np.int32), ncol - 2)
        iy = np.minimum(fy.astype(np.int32), nrow - 2)
        fx -= ix
        fy -= iy
        iy *= ncol
        iy += ix
        q = np.take(self._cells, iy, axis=0)                     # (..., 4) one gather
        bottom = q[..., 0] + fx * q[..., 1]
        top = q[..., 2] + fx * q[..., 3]
        top -= bottom
        top *= fy
        top += bottom
        return top

    # -- MuJoCo --------------------------------------------------------------------
    def hfield_spec(self) -> dict:
        """Everything a MuJoCo hfield asset + geom needs to reproduce ``heights``.

        MuJoCo's ``hfield_data`` (and MjSpec ``userdata``) put data row 0 at -y and column
        0 at -x (the MJCF ``elevation`` attribute is flipped: see ``mjcf``); it spreads them over
        [-rx, rx] x [-ry, ry] around the geom position and puts the surface at
        ``pos_z + data * elevation_z``; ``base_z`` is the depth of the box below pos_z.

        Returns:
            dict with nrow, ncol, size=(rx, ry, elevation_z, base_z), pos=(cx, cy, cz) and
            data: (nrow, ncol) float32 in [0, 1].
        """
        nrow, ncol = self.heights.shape
        hs = self.cfg.horizontal_scale
        lo, hi = float(self.heights.min()), float(self.heights.max())
        elevation = hi - lo if hi > lo else self.cfg.vertical_scale
        rx, ry = (ncol - 1) * hs / 2, (nrow - 1) * hs / 2
        data = ((self.heights.astype(np.float64) - lo) / elevation).astype(np.float32)
        return {"nrow": nrow, "ncol": ncol, "size": (rx, ry, elevation, self.cfg.base_depth),
                "pos": (self.x0 + rx, self.y0 + ry, lo), "data": data}

    def mjcf(self, name: str = "terrain", with_data: bool = True) -> tuple[str, str]:
        """MJCF ``<hfield>`` asset and ``<geom>`` elements for this terrain.

        MJCF's ``elevation`` attribute lists rows from +y down to -y (the reverse of
        ``hfield_data`` and MjSpec ``userdata``), so the rows are written flipped here. For
        big grids pass ``with_data=False`` and call ``apply_to_model`` after compiling.

        Args:
            name: hfield asset name (the geom gets the same name).
            with_data: include the elevation data in the asset element.
        """
        spec = self.hfield_spec()
        elevation = ""
        if with_data:
            values = " ".join(f"{v:.7g}" for v in spec["data"][::-1].ravel())
            elevation = f' elevation="{values}"'
        size = " ".join(f"{v:.9g}" for v in spec["size"])
        pos = " ".join(f"{v:.9g}" for v in spec["pos"])
        asset = (f'<hfield name="{name}" nrow="{spec["nrow"]}" ncol="{spec["ncol"]}" '
                 f'size="{size}"{elevation}/>')
        return asset, f'<geom name="{name}" type="hfield" hfield="{name}" pos="{pos}"/>'

    def apply_to_model(self, model, name: str = "terrain") -> None:
        """Copy the heights into a compiled MjModel's hfield ``name`` (same nrow/ncol/size).

        Args:
            model: a mujoco.MjModel whose hfield ``name`` was declared from ``hfield_spec``
                (nrow, ncol, size) without elevation data.
            name: the hfield asset name.
        """
        import mujoco  # lazy: the terrain is numpy; MuJoCo only when a model takes the heights

        spec = self.hfield_spec()
        hid = mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_HFIELD, name)
        if hid < 0:
            raise ValueError(f"model has no hfield named {name!r}")
        shape = (int(model.hfield_nrow[hid]), int(model.hfield_ncol[hid]))
        if shape != (spec["nrow"], spec["ncol"]):
            raise ValueError(f"hfield {name!r} is {shape}, terrain needs "
                             f"{(spec['nrow'], spec['ncol'])}")
        adr = int(model.hfield_adr[hid])
        model.hfield_data[adr: adr + shape[0] * shape[1]] = spec["data"].ravel()
        model.hfield_size[hid] = spec["size"]


# ----------------------------------------------------------------------------- curriculum
def update_levels(levels: np.ndarray, distance: np.ndarray, command_speed: np.ndarray,
                  episode_length_s: float, rng: np.random.Generator, num_levels: int,
                  max_init_level: int | None = None, *, tile_size: float = 8.0) -> np.ndarray:
    """legged_gym terrain curriculum, applied at the end of episodes.

    A robot that walked farther than half a tile moves up one level; one that walked less
    than half the distance its command asked for (|cmd| * T_ep * 0.5) moves down one; a
    robot that moves up from the top level is sent to a uniformly random level; levels are
    clipped at 0.

    Args:
        levels: (N,) current levels.
        distance: (N,) distance walked from the spawn point (m).
        command_speed: (N,) commanded planar speed |(vx, vy)| (m/s).
        episode_length_s: maximum episode length (s).
        rng: draws the random level for robots that solved the top level.
        num_levels: number of levels in the grid.
        max_init_level: unused by the legged_gym rule; accepted so callers can pass the
            config's value positionally.
        tile_size: tile side (m); the level-up threshold is tile_size / 2.

    Returns:
        (N,) int64 new levels in [0, num_levels).
    """
    levels = np.asarray(levels, dtype=np.int64)
    distance = np.asarray(distance, dtype=np.float64)
    move_up = distance > tile_size / 2
    move_down = (distance < np.abs(command_speed) * episode_length_s * 0.5) & ~move_up
    new = levels + move_up.astype(np.int64) - move_down.astype(np.int64)
    wrapped = rng.integers(0, num_levels, size=new.shape)
    return np.where(new >= num_levels, wrapped, np.maximum(new, 0))


def sample_initial(num_envs: int, rng: np.random.Generator, cfg: TerrainConfig,
                   type_weights: Mapping[str, float] | Sequence[float] | None = None,
                   ) -> tuple[np.ndarray, np.ndarray]:
    """Initial (type_idx, level) for ``num_envs`` robots.

    Types are split in proportion to ``type_weights`` (largest-remainder rounding, then
    shuffled) so every batch has the requested mix; levels are uniform in
    [0, max_init_level] with curriculum, else uniform over all levels.

    Args:
        num_envs: number of robots.
        rng: random generator.
        cfg: the terrain config.
        type_weights: per type, aligned with cfg.types or a {name: weight} mapping (missing
            names get 0); default uniform.
    """
    if isinstance(type_weights, Mapping):
        unknown = [k for k in type_weights if k not in cfg.types]
        if unknown:
            raise ValueError(f"type_weights names unknown type {unknown[0]!r}; "
                             f"grid types: {cfg.types}")
        weights = np.array([float(type_weights.get(k, 0.0)) for k in cfg.types])
    elif type_weights is None:
        weights = np.ones(len(cfg.types))
    else:
        weights = np.asarray(type_weights, dtype=np.float64)
        if weights.shape != (len(cfg.types),):
            raise ValueError(f"type_weights has shape {weights.shape}, "
                             f"expected ({len(cfg.types)},) for types {cfg.types}")
    if not np.all(np.isfinite(weights)) or np.any(weights < 0) or weights.sum() <= 0:
        raise ValueError(f"type_weights {weights.tolist()} must be finite, >= 0, sum > 0")
    share = weights / weights.sum() * num_envs
    counts = np.floor(share).astype(np.int64)
    counts[np.argsort(counts - share)[: num_envs - counts.sum()]] += 1
    type_idx = rng.permutation(np.repeat(np.arange(len(cfg.types)), counts))
    # max_init_level is capped by the grid: a 1-level grid needs no extra setting
    top = min(cfg.max_init_level, cfg.num_levels - 1) if cfg.curriculum else cfg.num_levels - 1
    return type_idx, rng.integers(0, top + 1, size=num_envs)
