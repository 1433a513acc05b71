"""Offscreen pictures of the batched env: one frame of a state, image strips (PNG) and short
videos (MP4). Films of a policy are taken through the one rollout loop
(:func:`msta.collect.rollout.film`)."""

from __future__ import annotations

import os
from pathlib import Path
from typing import Any

import mujoco
import numpy as np

from msta.collect.sim.robot import build_model
from msta.data.robot import A1, RobotDescription

GL_HELP = (
    "MuJoCo offscreen rendering needs an OpenGL backend. Set MUJOCO_GL=egl (needs libEGL, "
    "Debian/Ubuntu package 'libegl1' with Mesa's 'libgl1-mesa-dri') or MUJOCO_GL=osmesa "
    "(package 'libosmesa6'); on a desktop MUJOCO_GL=glfw works. Current MUJOCO_GL={!r}.{}")


def _no_display() -> str:
    """Why GLFW failed, when the reason is that there is no display to open a window on."""
    if os.environ.get("MUJOCO_GL", "glfw") != "glfw":
        return ""
    if os.environ.get("DISPLAY") or os.environ.get("WAYLAND_DISPLAY"):
        return ""
    return " GLFW opens a window and there is no display (DISPLAY is not set): use egl."


def make_renderer(model: mujoco.MjModel, height: int = 360, width: int = 480) -> mujoco.Renderer:
    """A renderer, or a RuntimeError that says which package provides a GL backend (see
    docs/simulator.md, "Rendering without a display")."""
    try:
        return mujoco.Renderer(model, height=height, width=width)
    except Exception as exc:  # mujoco raises FatalError/RuntimeError/AttributeError by backend
        raise RuntimeError(GL_HELP.format(os.environ.get("MUJOCO_GL"), _no_display())) from exc


def tracking_camera(distance: float = 1.6, azimuth: float = 135.0, elevation: float = -20.0
                    ) -> mujoco.MjvCamera:
    """A camera following the trunk from ``distance`` m, at ``azimuth`` degrees, looking down
    ``-elevation`` degrees."""
    cam = mujoco.MjvCamera()
    cam.type = mujoco.mjtCamera.mjCAMERA_TRACKING
    cam.trackbodyid = 1
    cam.distance, cam.azimuth, cam.elevation = distance, azimuth, elevation
    return cam


def render_state(renderer: mujoco.Renderer, model: mujoco.MjModel, data: mujoco.MjData,
                 state: np.ndarray, camera: mujoco.MjvCamera | None = None) -> np.ndarray:
    """One picture of a simulator state, the camera following the trunk.

    Args:
        renderer: from ``make_renderer(model, ...)``.
        model: the env's model (``QuadrupedEnv.model``).
        data: scratch ``MjData`` of ``model`` (overwritten).
        state: one row of ``QuadrupedEnv.state`` (MuJoCo's full-physics state).
        camera: default: a tracking camera 1.6 m away, looking down 20 degrees.
    Returns:
        (height, width, 3) uint8 frame (a copy).
    """
    mujoco.mj_setState(model, data, state, mujoco.mjtState.mjSTATE_FULLPHYSICS)
    mujoco.mj_forward(model, data)
    renderer.update_scene(data, camera=camera or tracking_camera())
    return renderer.render().copy()


class PatchRenderer:
    """Frames of the batched env drawn with only the terrain within ``radius`` m of the
    trunk: the same picture as :func:`render_state` on the env's model (the ground farther
    away is flat), several times faster without a GPU (the whole heightfield, 680,000 cells
    at the default size, is what a software OpenGL spends its time on).

    The renderer's own model is the env's robot over a square heightfield patch fixed at
    the origin. The patch holds the terrain around ``centre`` and the robot is drawn shifted
    by ``-centre`` (the camera follows the trunk, so the picture is the same); when the trunk
    is more than ``radius / 4`` from the centre, the patch is cut again around it and
    uploaded. Centres lie a whole number of metres from the full heightfield's centre, so
    the ground texture falls where it does on the whole terrain.

    Args:
        env_model: the env's model (``QuadrupedEnv.model``).
        terrain: the env's :class:`~msta.collect.sim.terrain.Terrain`.
        collision: the env's collision set (the geoms drawn are the same).
        height, width: frame size.
        radius: half the patch's side (m).
        shadows: draw shadows (with software OpenGL they take most of a frame's time).
        robot: the env's robot description (``QuadrupedEnv.robot``).
    """

    def __init__(self, env_model: mujoco.MjModel, terrain: Any, collision: str, height: int,
                 width: int, radius: float = 8.0, shadows: bool = True,
                 robot: RobotDescription = A1) -> None:
        self.terrain, self.radius = terrain, float(radius)
        heights, hs = terrain.heights, terrain.cfg.horizontal_scale
        self.lo = float(heights.min())
        self.elevation = max(float(heights.max()) - self.lo, terrain.cfg.vertical_scale)
        self.n = int(round(2 * self.radius / hs)) + 1
        side = (self.n - 1) * hs / 2
        # compiled from data spanning [0, 1]: the compiler rescales to that range (all-equal
        # heights gave NaN) and bounds the geom by it (the patches' heights come later)
        data = np.zeros((self.n, self.n), np.float32)
        data[0, 0] = 1.0
        self.model = build_model({"nrow": self.n, "ncol": self.n, "data": data,
                                  "pos": (0.0, 0.0, self.lo),
                                  "size": (side, side, self.elevation, terrain.cfg.base_depth)},
                                 timestep=env_model.opt.timestep, collision=collision,
                                 robot=robot)
        self.model.stat.extent = env_model.stat.extent
        self.light_pos = self.model.light_pos.copy()  # the shadows' frame follows the light
        self.renderer = make_renderer(self.model, height, width)
        self.renderer.scene.flags[mujoco.mjtRndFlag.mjRND_SHADOW] = int(shadows)
        self.data = mujoco.MjData(self.model)
        self.centre = np.array([np.inf, np.inf])

    def _cut(self, x: float, y: float) -> tuple[np.ndarray, np.ndarray]:
        """The patch's heights (as MuJoCo's [0, 1] data) around the grid sample nearest a
        whole-metre centre near (x, y), and that centre; outside the terrain's grid the
        ground is at z = 0."""
        t, n, hs = self.terrain, self.n, self.terrain.cfg.horizontal_scale
        rows, cols = t.heights.shape
        cx = round(x - (cols - 1) * hs / 2 - t.x0) + (cols - 1) * hs / 2 + t.x0
        cy = round(y - (rows - 1) * hs / 2 - t.y0) + (rows - 1) * hs / 2 + t.y0
        ix0 = int(round((cx - t.x0) / hs)) - (n - 1) // 2
        iy0 = int(round((cy - t.y0) / hs)) - (n - 1) // 2
        patch = np.zeros((n, n), np.float32)
        r0, r1, c0, c1 = max(iy0, 0), min(iy0 + n, rows), max(ix0, 0), min(ix0 + n, cols)
        if r1 > r0 and c1 > c0:
            patch[r0 - iy0:r1 - iy0, c0 - ix0:c1 - ix0] = t.heights[r0:r1, c0:c1]
        data = ((patch - self.lo) / self.elevation).astype(np.float32)
        mid = (n - 1) / 2 * hs
        return data, np.array([t.x0 + ix0 * hs + mid, t.y0 + iy0 * hs + mid])

    def _follow(self, xy: np.ndarray) -> None:
        if np.abs(xy - self.centre).max() <= self.radius / 4:
            return
        data, self.centre = self._cut(float(xy[0]), float(xy[1]))
        self.model.hfield_data[:] = data.ravel()
        self.model.light_pos[:] = self.light_pos - np.array([*self.centre, 0.0])
        # into this renderer's own GL context (another renderer's may be current); mujoco's
        # Renderer has no public call for an upload
        if self.renderer._gl_context:
            self.renderer._gl_context.make_current()
        mujoco.mjr_uploadHField(self.model, self.renderer._mjr_context, 0)

    def render(self, state: np.ndarray, camera: mujoco.MjvCamera | None = None) -> np.ndarray:
        """The (height, width, 3) uint8 frame of one row of ``QuadrupedEnv.state``."""
        self._follow(np.asarray(state[1:3], np.float64))  # the trunk's x, y (after the time)
        local = np.array(state, np.float64)
        local[1:3] -= self.centre
        return render_state(self.renderer, self.model, self.data, local, camera)

    def close(self) -> None:
        self.renderer.close()


def save_strip(frames: list[np.ndarray], path: str | Path, columns: int = 6) -> Path:
    """Tile up to ``columns`` evenly spaced frames side by side into one PNG."""
    import matplotlib.image  # lazy: matplotlib (~0.5 s) loads only when a picture is drawn

    if not frames:
        raise ValueError("no frames to save")
    pick = np.linspace(0, len(frames) - 1, min(columns, len(frames))).round().astype(int)
    strip = np.concatenate([frames[i] for i in pick], axis=1)
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    matplotlib.image.imsave(path, strip)
    return path


def save_video(frames: list[np.ndarray], path: str | Path, fps: int = 10) -> Path:
    """Encode frames as H.264 MP4 with PyAV (installed with lerobot)."""
    import av  # lazy: PyAV loads only when a video is written

    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    h, w = frames[0].shape[:2]
    with av.open(str(path), mode="w") as out:
        stream = out.add_stream("libx264", rate=fps)
        stream.width, stream.height, stream.pix_fmt = w - w % 2, h - h % 2, "yuv420p"
        for f in frames:
            frame = av.VideoFrame.from_ndarray(f[: h - h % 2, : w - w % 2], format="rgb24")
            for packet in stream.encode(frame):
                out.mux(packet)
        for packet in stream.encode():
            out.mux(packet)
    return path
