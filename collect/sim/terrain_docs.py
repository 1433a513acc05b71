"""PNG pictures of the terrain grid for docs/ (``python -m msta.collect.sim.terrain_docs --docs docs/``).

Only this module imports :mod:`msta.collect.sim.terrain` for the pictures; the terrain module
does not import it back.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from msta.collect.sim.terrain import Terrain, TerrainConfig
from msta.data.cli import parse_config

DOC_LEVELS = (0, 4, 9)


def _tile_heights(terrain: Terrain, type_idx: int, level: int) -> np.ndarray:
    n, b = terrain.cfg.tile_samples, terrain.cfg.border_samples
    col = type_idx * terrain.cfg.columns_per_type
    return terrain.heights[b + level * n: b + (level + 1) * n + 1,
                           b + col * n: b + (col + 1) * n + 1]


def plot_type(terrain: Terrain, name: str, path: Path, levels: Sequence[int] = DOC_LEVELS) -> None:
    """Save a PNG of one terrain type at a few levels: 3D surfaces over centre-line profiles.

    Args:
        terrain: the grid.
        name: terrain type name.
        path: output PNG.
        levels: levels to show (those >= num_levels are skipped).
    """
    import matplotlib  # lazy: matplotlib (~0.5 s) loads only when a picture is drawn
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt  # lazy: matplotlib (~0.5 s) loads only when a picture is drawn

    # lazy: matplotlib (~0.5 s) loads only when a picture is drawn
    from matplotlib.colors import LightSource

    cfg, t = terrain.cfg, terrain.level_type_index(name)
    levels = [lv for lv in levels if lv < cfg.num_levels]
    tiles = [_tile_heights(terrain, t, lv) for lv in levels]
    zmax = max(0.25, *(float(np.abs(z).max()) for z in tiles))
    xs = np.arange(tiles[0].shape[1]) * cfg.horizontal_scale - cfg.tile_size / 2
    xx, yy = np.meshgrid(xs, xs)
    fig = plt.figure(figsize=(5 * len(levels), 6.4))
    for k, (level, z) in enumerate(zip(levels, tiles)):
        ax = fig.add_subplot(2, len(levels), k + 1, projection="3d")
        ax.plot_surface(xx, yy, z, cmap="terrain", vmin=-zmax, vmax=zmax, rstride=1, cstride=1,
                        linewidth=0, antialiased=False, lightsource=LightSource(315, 45))
        ax.set(zlim=(-zmax, zmax), xlabel="x (m)", ylabel="y (m)", zlabel="z (m)")
        ax.set_box_aspect((1, 1, 0.5))
        ax.view_init(elev=35, azim=-60)
        centre = z[z.shape[0] // 2, z.shape[1] // 2]
        ax.set_title(f"{name}  level {level} (d={level / cfg.num_levels:.1f})\n"
                     f"z in [{z.min():+.3f}, {z.max():+.3f}] m, centre {centre:+.3f} m")
        prof = fig.add_subplot(2, len(levels), len(levels) + k + 1)
        prof.plot(xs, z[z.shape[0] // 2], drawstyle="steps-mid", color="tab:brown")
        prof.set(ylim=(-zmax * 1.05, zmax * 1.05), xlabel="x (m) along y = 0", ylabel="z (m)")
        prof.grid(alpha=0.3)
    fig.tight_layout()
    fig.savefig(path, dpi=80)
    plt.close(fig)


def plot_grid(terrain: Terrain, path: Path) -> None:
    """Save a shaded-relief PNG of the whole grid (border trimmed to 1 m).

    Args:
        terrain: the grid.
        path: output PNG.
    """
    import matplotlib  # lazy: matplotlib (~0.5 s) loads only when a picture is drawn
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt  # lazy: matplotlib (~0.5 s) loads only when a picture is drawn

    # lazy: matplotlib (~0.5 s) loads only when a picture is drawn
    from matplotlib.colors import LightSource

    cfg = terrain.cfg
    keep = terrain.cfg.border_samples - min(cfg.border_samples, round(1.0 / cfg.horizontal_scale))
    z = terrain.heights[keep: terrain.heights.shape[0] - keep, keep: terrain.heights.shape[1] - keep]
    lo = terrain.x0 + keep * cfg.horizontal_scale
    extent = (lo, lo + (z.shape[1] - 1) * cfg.horizontal_scale,
              lo, lo + (z.shape[0] - 1) * cfg.horizontal_scale)
    rgb = LightSource(azdeg=315, altdeg=40).shade(
        z, cmap=plt.get_cmap("terrain"), vert_exag=3, blend_mode="soft",
        vmin=-1.8, vmax=1.8, dx=cfg.horizontal_scale, dy=cfg.horizontal_scale)
    fig, ax = plt.subplots(figsize=(2 + 1.3 * terrain.num_columns, 1 + 1.0 * cfg.num_levels))
    ax.imshow(rgb, origin="lower", extent=extent, interpolation="nearest")
    mappable = plt.cm.ScalarMappable(cmap="terrain", norm=plt.Normalize(-1.8, 1.8))
    fig.colorbar(mappable, ax=ax, label="height (m)", shrink=0.6)
    ticks = (np.arange(terrain.num_columns) + 0.5) * cfg.tile_size
    labels = [cfg.types[c // cfg.columns_per_type] for c in range(terrain.num_columns)]
    ax.set_xticks(ticks, labels, rotation=30, ha="right")
    ax.set_yticks((np.arange(cfg.num_levels) + 0.5) * cfg.tile_size,
                  [f"L{lv} d={lv / cfg.num_levels:.1f}" for lv in range(cfg.num_levels)])
    ax.set_title(f"terrain grid (seed {terrain.seed}): columns = types, rows = levels; "
                 f"world x right, y up")
    fig.tight_layout()
    fig.savefig(path, dpi=80)
    plt.close(fig)


def write_docs(out_dir: Path, seed: int = 0, cfg: TerrainConfig | None = None) -> list[Path]:
    """Write terrain_<type>.png for every type and terrain_grid.png into ``out_dir``.

    Args:
        out_dir: destination folder (created if missing).
        seed: terrain seed.
        cfg: grid config; default TerrainConfig() with a 1 m border.
    """
    cfg = cfg or TerrainConfig(border=1.0)
    out_dir.mkdir(parents=True, exist_ok=True)
    terrain = Terrain(cfg, seed=seed)
    paths = []
    for name in cfg.types:
        paths.append(out_dir / f"terrain_{name}.png")
        plot_type(terrain, name, paths[-1])
    paths.append(out_dir / "terrain_grid.png")
    plot_grid(terrain, paths[-1])
    return paths


@dataclass
class DocsConfig:
    """Args:
        docs: folder the PNGs are written to (created if missing).
        seed: terrain seed.
    """

    docs: Path = Path("docs")
    seed: int = 0


def main(argv: Sequence[str] | None = None) -> None:
    """CLI: ``python -m msta.collect.sim.terrain_docs --docs docs/`` prints each PNG written."""
    cfg = parse_config(DocsConfig, argv, prog="python -m msta.collect.sim.terrain_docs")
    for path in write_docs(cfg.docs, seed=cfg.seed):
        print(path)


if __name__ == "__main__":
    main()
