"""Offscreen pictures of the batched env: one frame of a state, image strips (PNG) and short
videos (MP4). Films of a policy are taken through the one rollout loop
(:func:`msta.collect.rollout.film`)."""

from __future__ import annotations

import os
from pathlib import Path

import mujoco
import numpy as np

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
