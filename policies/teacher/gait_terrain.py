"""Height-scan lookups for the gait teacher.

The privileged ``height_scan`` holds terrain height minus base height on a 17 x 11 grid
(x in [-0.8, 0.8] major, y in [-0.5, 0.5], 0.1 m spacing) in the yaw-aligned frame centred
on the base. The gait teacher plans feet in that same frame, so a foothold's ground height
is a bilinear lookup in the scan.
"""

from __future__ import annotations

import numpy as np

from msta.data.sensors import HEIGHT_SCAN_X, HEIGHT_SCAN_Y

NX, NY = len(HEIGHT_SCAN_X), len(HEIGHT_SCAN_Y)
X0, Y0, STEP = HEIGHT_SCAN_X[0], HEIGHT_SCAN_Y[0], 0.1


def scan_grid(scan: np.ndarray) -> np.ndarray:
    """(N, 187) x-major scan -> (N, 17, 11) grid [n, ix, iy]."""
    return np.asarray(scan, dtype=np.float64).reshape(len(scan), NX, NY)


def ground_at(grid: np.ndarray, xy: np.ndarray) -> np.ndarray:
    """Bilinear ground height (relative to the base) at points of the yaw-aligned frame.

    Points outside the scan are clamped to its border.

    Args:
        grid: (N, 17, 11) from ``scan_grid``.
        xy: (N, ..., 2) query points.
    Returns:
        (N, ...) heights.
    """
    shape = xy.shape[:-1]
    xy = xy.reshape(len(xy), -1, 2)
    fx = np.clip((xy[..., 0] - X0) / STEP, 0.0, NX - 1 - 1e-6)
    fy = np.clip((xy[..., 1] - Y0) / STEP, 0.0, NY - 1 - 1e-6)
    ix, iy = np.floor(fx).astype(np.int64), np.floor(fy).astype(np.int64)
    tx, ty = fx - ix, fy - iy
    n = np.arange(len(grid))[:, None]
    h00, h10 = grid[n, ix, iy], grid[n, ix + 1, iy]
    h01, h11 = grid[n, ix, iy + 1], grid[n, ix + 1, iy + 1]
    out = h00 * (1 - tx) * (1 - ty) + h10 * tx * (1 - ty) + h01 * (1 - tx) * ty + h11 * tx * ty
    return out.reshape(shape)


def dilate(grid: np.ndarray) -> np.ndarray:
    """3 x 3 max filter of the scan grid (each cell: highest ground within 0.1 m)."""
    pad = np.pad(grid, ((0, 0), (1, 1), (1, 1)), mode="edge")
    out = grid.copy()
    for dx in range(3):
        for dy in range(3):
            np.maximum(out, pad[:, dx:dx + NX, dy:dy + NY], out=out)
    return out


def ground_max_along(dilated: np.ndarray, start: np.ndarray, end: np.ndarray,
                     samples: int = 5) -> np.ndarray:
    """Highest ground near the segments ``start -> end`` (both (N, K, 2)): (N, K).

    Args:
        dilated: (N, 17, 11) from ``dilate(scan_grid(scan))``.
        start, end: segment end points in the yaw-aligned frame.
        samples: points per segment.
    """
    t = np.linspace(0.0, 1.0, samples)[:, None]                                  # (S, 1)
    pts = start[..., None, :] + t * (end - start)[..., None, :]                  # (N, K, S, 2)
    return ground_at(dilated, pts).max(axis=-1)


def _window(grid: np.ndarray, half_x: float, half_y: float) -> np.ndarray:
    """The scan points with |x| <= half_x and |y| <= half_y: (N, nx, ny)."""
    xs = np.abs(np.asarray(HEIGHT_SCAN_X)) <= half_x + 1e-9
    ys = np.abs(np.asarray(HEIGHT_SCAN_Y)) <= half_y + 1e-9
    return grid[:, xs][:, :, ys]


def body_reference(grid: np.ndarray, half_x: float = 0.3, half_y: float = 0.2) -> np.ndarray:
    """Mean ground height under the body footprint (|x| <= half_x, |y| <= half_y): (N,)."""
    return _window(grid, half_x, half_y).mean(axis=(1, 2))


def roughness(grid: np.ndarray, half_x: float = 0.6, half_y: float = 0.4) -> np.ndarray:
    """Largest |second difference| of the scan within |x| <= half_x, |y| <= half_y: (N,).
    0 on planes and slopes, about the riser height at a step, a few cm on rough slopes."""
    g = _window(grid, half_x, half_y)
    d2x = np.abs(g[:, 2:] - 2 * g[:, 1:-1] + g[:, :-2]).max(axis=(1, 2))
    d2y = np.abs(g[:, :, 2:] - 2 * g[:, :, 1:-1] + g[:, :, :-2]).max(axis=(1, 2))
    return np.maximum(d2x, d2y)


__all__ = ["body_reference", "dilate", "ground_at", "ground_max_along", "roughness",
           "scan_grid"]
