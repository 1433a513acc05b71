"""Tests for collect/sim/terrain.py: tile parameterization, determinism, lookups,
curriculum, and that a real MuJoCo hfield reproduces the heights."""

from __future__ import annotations

import draccus
import mujoco
import numpy as np
import pytest

from msta.collect.sim.terrain import (
    LEGGED_GYM_TYPE_WEIGHTS,
    TERRAIN_TYPES,
    TILE_GENERATORS,
    Terrain,
    TerrainConfig,
    sample_initial,
    stair_step_height,
    update_levels,
)
from msta.collect.sim.terrain_docs import main as docs_main
from msta.collect.sim.terrain_docs import write_docs

Q = 0.005  # vertical quantization


@pytest.fixture(scope="module")
def full() -> Terrain:
    """The default legged_gym-sized grid (6 types x 10 levels of 8 m tiles), small border."""
    return Terrain(TerrainConfig(border=1.0), seed=3)


def tile(t: Terrain, name: str, level: int, repeat: int = 0) -> np.ndarray:
    """(n, n) heights of one tile; local sample (n//2, n//2) is the tile centre."""
    n, b = t.cfg.tile_samples, t.cfg.border_samples
    col = t.level_type_index(name) * t.cfg.columns_per_type + repeat
    return t.heights[b + level * n: b + (level + 1) * n, b + col * n: b + (col + 1) * n]


def centre_row(t: Terrain, name: str, level: int) -> np.ndarray:
    """Heights along y = tile centre, from the tile's -x edge to its centre (inclusive)."""
    z = tile(t, name, level)
    n = z.shape[0]
    return z[n // 2, : n // 2 + 1].astype(np.float64)


def test_registry_matches_public_types():
    assert tuple(TILE_GENERATORS) == TERRAIN_TYPES


def test_grid_shape_and_origin(full):
    cfg = full.cfg
    assert full.heights.shape == (10 * 80 + 2 * 10 + 1, 6 * 80 + 2 * 10 + 1)
    assert full.heights.dtype == np.float32
    assert full.x0 == full.y0 == pytest.approx(-1.0)
    # every height is on the vertical grid; the border is flat at 0
    assert np.allclose(np.round(full.heights / Q) * Q, full.heights, atol=1e-6)
    assert np.all(full.heights[:10] == 0) and np.all(full.heights[:, -10:] == 0)
    assert cfg.types == TERRAIN_TYPES


def test_flat_is_zero(full):
    for level in range(10):
        assert np.all(tile(full, "flat", level) == 0)


@pytest.mark.parametrize("level", range(10))
def test_smooth_slope_gradient_and_platform(full, level):
    d = level / 10
    row = centre_row(full, "smooth_slope", level)
    x = np.arange(len(row)) * 0.1                     # 0 at the tile edge, 4.0 at the centre
    on_slope = x <= 2.5
    gradient = np.polyfit(x[on_slope], row[on_slope], 1)[0]
    assert gradient == pytest.approx(0.4 * d, abs=0.003)
    assert row[0] == 0
    z = tile(full, "smooth_slope", level)
    # summit: a flat 3 m platform at height 0.4 d * 2.5 m; nothing higher
    platform = z[40 - 15: 40 + 16, 40 - 15: 40 + 16]
    assert np.all(np.abs(platform - 0.4 * d * 2.5) <= Q / 2 + 1e-6)
    assert z.max() == pytest.approx(platform.max())
    assert z.min() == 0


@pytest.mark.parametrize("level", [0, 4, 9])
def test_rough_slope_is_slope_plus_bounded_noise(full, level):
    noise = tile(full, "rough_slope", level).astype(np.float64) \
        - tile(full, "smooth_slope", level)
    assert np.abs(noise).max() <= 0.05 + Q + 1e-6
    assert 0.015 < noise.std() < 0.04                  # noise is really there
    assert abs(noise.mean()) < 0.005


@pytest.mark.parametrize("level", range(10))
@pytest.mark.parametrize("name,sign", [("stairs_up", -1), ("stairs_down", +1)])
def test_stairs_step_height_tread_and_direction(full, name, sign, level):
    step = 0.05 + 0.18 * level / 10
    assert stair_step_height(level / 10, Q) == pytest.approx(step, abs=Q / 2 + 1e-9)
    row = centre_row(full, name, level)
    risers = np.diff(row)
    jumps = risers[np.abs(risers) > 1e-6]
    assert len(jumps) == 8                              # floor((4 - 1.5) / 0.31) steps
    assert np.allclose(jumps, sign * stair_step_height(level / 10, Q), atol=1e-6)
    treads = np.diff(np.flatnonzero(np.abs(risers) > 1e-6)) * 0.1
    assert set(np.round(treads, 1)) <= {0.3, 0.4} and np.mean(treads) == pytest.approx(0.31, abs=0.02)
    # centre platform (>= 3 m) is the pit (up) or the top (down); the edge is at 0
    z = tile(full, name, level)
    assert row[0] == 0
    assert np.all(z[40 - 15: 40 + 16, 40 - 15: 40 + 16] == row[-1])
    assert row[-1] == pytest.approx(sign * 8 * stair_step_height(level / 10, Q), abs=1e-5)


@pytest.mark.parametrize("level", [0, 5, 9])
def test_discrete_obstacle_heights_and_platform(full, level):
    h = 0.05 + 0.2 * level / 10
    z = tile(full, "discrete", level).astype(np.float64)
    allowed = np.round(np.array([0, h, -h, h / 2, -h / 2]) / Q) * Q
    assert np.all(np.min(np.abs(z.ravel()[:, None] - allowed[None]), axis=1) < 1e-6)
    assert np.all(z[40 - 15: 40 + 16, 40 - 15: 40 + 16] == 0)
    assert np.abs(z).max() == pytest.approx(np.round(h / Q) * Q, abs=1e-6)
    assert (z != 0).mean() > 0.2                          # 20 rectangles of 1-2 m cover a lot


def test_determinism_from_seed():
    cfg = TerrainConfig(num_levels=3, max_init_level=1, border=0.5)
    a, b, c = Terrain(cfg, seed=7), Terrain(cfg, seed=7), Terrain(cfg, seed=8)
    assert np.array_equal(a.heights, b.heights)
    for name in TERRAIN_TYPES:
        for level in range(3):
            same = np.array_equal(tile(a, name, level), tile(c, name, level))
            assert same == (name not in ("rough_slope", "discrete")), (name, level)
    # a tile's content does not depend on the order of the other types
    swapped = Terrain(TerrainConfig(types=("discrete", "rough_slope"), num_levels=3,
                                    max_init_level=1, border=0.5), seed=7)
    assert np.array_equal(tile(swapped, "discrete", 2), tile(a, "discrete", 2))


def test_columns_per_type_repeats_differ_for_random_types():
    cfg = TerrainConfig(types=("stairs_up", "discrete"), num_levels=2, columns_per_type=2,
                        max_init_level=0, border=0.5)
    t = Terrain(cfg, seed=1)
    assert t.heights.shape[1] == 4 * 80 + 2 * 5 + 1
    assert np.array_equal(tile(t, "stairs_up", 1, 0), tile(t, "stairs_up", 1, 1))
    assert not np.array_equal(tile(t, "discrete", 1, 0), tile(t, "discrete", 1, 1))
    centres = t.tile_center(np.array([1, 1]), np.array([0, 0]), column=np.array([0, 1]))
    assert np.allclose(centres[:, :2], [[20.0, 4.0], [28.0, 4.0]])
    type_idx, level = t.tile_of(centres[:, :2])
    assert type_idx.tolist() == [1, 1] and level.tolist() == [0, 0]
    drawn = t.tile_center(np.zeros(200, int), np.ones(200, int), rng=np.random.default_rng(0))
    assert set(np.round(drawn[:, 0], 6)) == {4.0, 12.0}


def test_tile_center_and_tile_of_roundtrip(full):
    type_idx, level = np.meshgrid(np.arange(6), np.arange(10), indexing="ij")
    type_idx, level = type_idx.ravel(), level.ravel()
    c = full.tile_center(type_idx, level)
    assert c.shape == (60, 3)
    assert np.allclose(c[:, 0], type_idx * 8 + 4) and np.allclose(c[:, 1], level * 8 + 4)
    assert np.allclose(c[:, 2], full.height_at(c[:, :2]), atol=1e-6)
    stairs = full.level_type_index("stairs_down")
    top = full.tile_center(np.array([stairs]), np.array([9]))[0, 2]
    assert top == pytest.approx(8 * stair_step_height(0.9, Q), abs=1e-5)
    got_t, got_l = full.tile_of(c[:, :2] + np.array([3.9, -3.9]))
    assert np.array_equal(got_t, type_idx) and np.array_equal(got_l, level)
    border_t, border_l = full.tile_of(np.array([[-0.5, 3.0], [10.0, 80.5], [48.2, 3.0]]))
    assert border_t.tolist() == [-1, -1, -1] and border_l.tolist() == [-1, -1, -1]


def test_height_at_samples_interpolation_and_clamping(full):
    rng = np.random.default_rng(0)
    nrow, ncol = full.heights.shape
    iy, ix = rng.integers(0, nrow - 1, 500), rng.integers(0, ncol - 1, 500)
    xy = np.stack([full.x0 + ix * 0.1, full.y0 + iy * 0.1], axis=-1)
    assert np.allclose(full.height_at(xy), full.heights[iy, ix], atol=1e-5)
    # bilinear at an interior point: weights (1 - tx)(1 - ty) etc.
    tx, ty = 0.3, 0.8
    h = full.heights.astype(np.float64)
    expected = ((1 - tx) * (1 - ty) * h[iy, ix] + tx * (1 - ty) * h[iy, ix + 1]
                + (1 - tx) * ty * h[iy + 1, ix] + tx * ty * h[iy + 1, ix + 1])
    got = full.height_at(xy + np.array([tx * 0.1, ty * 0.1]))
    assert np.allclose(got, expected, atol=1e-4)
    # shape (..., 2) -> (...), and points far outside take the edge value
    assert full.height_at(xy.reshape(10, 50, 2)).shape == (10, 50)
    far = np.array([[-100.0, -100.0], [1e4, 1e4], [24.0, -50.0]])
    assert np.allclose(full.height_at(far), [h[0, 0], h[-1, -1], h[0, 250]])


def test_bad_input_errors(full):
    with pytest.raises(ValueError, match="'lava'"):
        TerrainConfig(types=("flat", "lava"))
    with pytest.raises(ValueError, match="max_init_level=-1"):
        TerrainConfig(max_init_level=-1)
    # a small grid needs no extra setting: initial levels are capped by the grid
    one = TerrainConfig(types=("flat",), num_levels=2)
    _, levels = sample_initial(50, np.random.default_rng(0), one)
    assert set(levels.tolist()) == {0, 1}
    with pytest.raises(ValueError, match="tile_size=8.05"):
        TerrainConfig(tile_size=8.05)
    with pytest.raises(ValueError, match="level 10 out of range"):
        full.tile_center(np.array([0, 1]), np.array([3, 10]))
    with pytest.raises(ValueError, match="type_idx -1 out of range"):
        full.tile_center(np.array([-1]), np.array([0]))
    with pytest.raises(ValueError, match="column 1 out of range"):
        full.tile_center(np.array([0]), np.array([0]), column=1)
    with pytest.raises(ValueError, match="'ice'"):
        full.level_type_index("ice")
    with pytest.raises(ValueError, match="seed=-1"):
        Terrain(TerrainConfig(num_levels=1, max_init_level=0), seed=-1)


def test_config_parses_with_draccus_and_rejects_unknown_keys():
    cfg = draccus.parse(config_class=TerrainConfig,
                        args=["--types=[flat,stairs_up]", "--num_levels=4", "--max_init_level=2"])
    assert cfg.types == ("flat", "stairs_up") and cfg.num_levels == 4
    with pytest.raises(SystemExit):
        draccus.parse(config_class=TerrainConfig, args=["--num_level=4"])
    with pytest.raises(draccus.utils.ParsingError, match="TerrainConfig"):
        draccus.parse(config_class=TerrainConfig, args=["--types=[flat,lava]"])


def test_curriculum_up_down_stay_clip_and_wrap():
    rng = np.random.default_rng(0)
    levels = np.array([3, 3, 3, 0, 5, 3])
    distance = np.array([4.5, 1.0, 3.0, 0.5, 5.0, 4.0])
    speed = np.array([1.0, 1.0, 0.2, 1.0, 1.0, 0.3])
    # T_ep = 20 s: down threshold = |cmd| * 10 m -> 10, 10, 2, 10, 10, 3
    new = update_levels(levels, distance, speed, 20.0, rng, 10, 5)
    # up (> 4 m, even though < 10 m asked); down; stay; clip at 0; up; stay (4.0 is not > 4)
    assert new.tolist() == [4, 2, 3, 0, 6, 3]
    wrapped = update_levels(np.full(2000, 9), np.full(2000, 6.0), np.ones(2000), 20.0,
                            rng, 10, 5)
    assert wrapped.min() >= 0 and wrapped.max() <= 9 and len(set(wrapped.tolist())) == 10
    assert update_levels(np.array([2]), np.array([3.0]), np.array([0.0]), 20.0, rng, 10, 5,
                         tile_size=4.0).tolist() == [3]


def test_sample_initial_mix_and_levels():
    rng = np.random.default_rng(0)
    cfg = TerrainConfig()
    t, lv = sample_initial(1000, rng, cfg, LEGGED_GYM_TYPE_WEIGHTS)
    assert np.bincount(t, minlength=6).tolist() == [0, 100, 100, 350, 250, 200]
    assert lv.min() == 0 and lv.max() == 5
    t, lv = sample_initial(7, rng, cfg)
    assert sorted(np.bincount(t, minlength=6).tolist()) == [1, 1, 1, 1, 1, 2]
    _, lv = sample_initial(2000, rng, TerrainConfig(curriculum=False))
    assert lv.max() == 9
    with pytest.raises(ValueError, match="'snow'"):
        sample_initial(4, rng, cfg, {"snow": 1.0})
    with pytest.raises(ValueError, match="shape"):
        sample_initial(4, rng, cfg, [1.0, 2.0])


# ----------------------------------------------------------------------------- MuJoCo
def _small() -> Terrain:
    cfg = TerrainConfig(types=("smooth_slope", "stairs_up", "discrete", "rough_slope"),
                        num_levels=2, tile_size=3.0, platform_size=1.0, border=0.5,
                        max_init_level=1)
    return Terrain(cfg, seed=2)


def _models(t: Terrain) -> dict[str, mujoco.MjModel]:
    """The same terrain loaded into MuJoCo three ways."""
    s = t.hfield_spec()
    sphere = '<body name="ball" pos="0 0 3"><freejoint/><geom type="sphere" size="0.05" group="3"/></body>'

    def from_xml(with_data: bool) -> mujoco.MjModel:
        asset, geom = t.mjcf(with_data=with_data)
        return mujoco.MjModel.from_xml_string(
            f"<mujoco><asset>{asset}</asset><worldbody>{geom}{sphere}</worldbody></mujoco>")

    applied = from_xml(False)
    t.apply_to_model(applied)
    spec = mujoco.MjSpec()
    hf = spec.add_hfield(name="terrain", nrow=s["nrow"], ncol=s["ncol"], size=list(s["size"]))
    hf.userdata = s["data"].ravel().tolist()
    spec.worldbody.add_geom(type=mujoco.mjtGeom.mjGEOM_HFIELD, hfieldname="terrain",
                            pos=list(s["pos"]))
    return {"xml": from_xml(True), "apply_to_model": applied, "mjspec": spec.compile()}


def _ray_heights(model: mujoco.MjModel, xy: np.ndarray) -> np.ndarray:
    data = mujoco.MjData(model)
    mujoco.mj_forward(model, data)
    geomid = np.zeros(1, np.int32)
    terrain_only = np.array([1, 0, 0, 0, 0, 0], np.uint8)      # the ball is in group 3
    out = []
    for x, y in xy:
        dist = mujoco.mj_ray(model, data, np.array([x, y, 20.0]), np.array([0.0, 0.0, -1.0]),
                             terrain_only, 1, -1, geomid)
        out.append(20.0 - dist if dist >= 0 else np.nan)
    return np.array(out)


def test_mujoco_hfield_reproduces_heights():
    """Ray-cast every cell of the hfield, loaded three ways, at an interior point.

    MuJoCo splits each cell into two triangles while height_at is bilinear: they agree
    exactly on cells whose corners are coplanar (twist 0: flat cells, slope faces, stair
    treads, obstacle tops) and differ by at most |twist| / 4 elsewhere.
    """
    t = _small()
    s = t.hfield_spec()
    assert s["data"].shape == t.heights.shape and s["data"].min() == 0 and s["data"].max() == 1
    h = t.heights.astype(np.float64)
    twist = np.abs(h[:-1, :-1] + h[1:, 1:] - h[:-1, 1:] - h[1:, :-1]).ravel()
    iy, ix = np.meshgrid(np.arange(s["nrow"] - 1), np.arange(s["ncol"] - 1), indexing="ij")
    xy = np.stack([t.x0 + (ix.ravel() + 0.3) * 0.1, t.y0 + (iy.ravel() + 0.6) * 0.1], -1)
    expected = t.height_at(xy)
    assert (twist < 1e-6).mean() > 0.8 and np.ptp(expected) > 0.5   # a real test surface
    for route, model in _models(t).items():
        err = np.abs(_ray_heights(model, xy) - expected)
        assert np.all(err[twist < 1e-6] < 0.002), route
        assert np.all(err <= twist / 4 + 0.002), route


def test_mujoco_sphere_rests_on_height_at():
    t = _small()
    model = _models(t)["apply_to_model"]
    stairs = t.level_type_index("stairs_up")
    spots = np.array([t.tile_center(np.array([stairs]), np.array([1]))[0, :2],  # pit platform
                      [0.9, 0.75],                                              # slope, level 0
                      [2.0, 4.5]])                                              # slope, level 1
    for xy in spots:
        data = mujoco.MjData(model)
        data.qpos[:3] = [xy[0], xy[1], t.height_at(xy) + 0.3]
        for _ in range(600):
            mujoco.mj_step(model, data)
        rest = data.qpos[2] - 0.05
        assert abs(rest - t.height_at(data.qpos[:2])) < 0.015, (xy, rest)


def test_docs_writes_pngs(tmp_path):
    cfg = TerrainConfig(types=("stairs_up", "discrete"), tile_size=3.0, platform_size=1.0,
                        border=0.5)
    paths = write_docs(tmp_path, seed=1, cfg=cfg)
    names = sorted(p.name for p in tmp_path.iterdir())
    assert names == ["terrain_discrete.png", "terrain_grid.png", "terrain_stairs_up.png"]
    assert sorted(p.name for p in paths) == names
    for p in tmp_path.iterdir():
        assert p.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n" and p.stat().st_size > 5000


def test_docs_cli_options(capsys):
    """The --docs entry point lives in terrain_docs (terrain.py does not import it back):
    --help lists its options with defaults; a misspelled option is one line, exit 2."""
    from pathlib import Path

    from msta.collect.sim import terrain

    assert "terrain_docs" not in Path(terrain.__file__).read_text() and not hasattr(terrain, "main")
    with pytest.raises(SystemExit) as e:
        docs_main(["--help"])
    assert e.value.code == 0
    out = capsys.readouterr().out
    assert "--docs" in out and "(default: docs)" in out and "terrain seed" in out
    with pytest.raises(SystemExit) as e:
        docs_main(["--doc=x"])
    assert e.value.code == 2
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and "did you mean --docs" in err
