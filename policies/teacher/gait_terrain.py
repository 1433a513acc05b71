"""Height-scan lookups for the gait teacher.

The privileged ``height_scan`` holds terrain height minus base height on a 17 x 11 grid
(x in [-0.8, 0.8] major, y in [-0.5, 0.5], 0.1 m spacing) in the yaw-aligned frame centred
on the base. The gait teacher plans feet in that same frame, so a foothold's ground height
is a bilinear lookup in the scan.
"""

from __future__ import annotations

import numpy as np

from msta_data.sensors import HEIGHT_SCAN_X, HEIGHT_SCAN_Y

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
        xy: (N, K, 2) query points.
    Returns:
        (N, K) heights.
    """
    fx = np.clip((xy[..., 0] - X0) / STEP, 0.0, NX - 1 - 1e-6)
    fy = np.clip((xy[..., 1] - Y0) / STEP, 0.0, NY - 1 - 1e-6)
    ix, iy = np.floor(fx).astype(np.int64), np.floor(fy).astype(np.int64)
    tx, ty = fx - ix, fy - iy
    n = np.arange(len(grid))[:, None]
    h00, h10 = grid[n, ix, iy], grid[n, ix + 1, iy]
    h01, h11 = grid[n, ix, iy + 1], grid[n, ix + 1, iy + 1]
    return (h00 * (1 - tx) * (1 - ty) + h10 * tx * (1 - ty) + h01 * (1 - tx) * ty
            + h11 * tx * ty)


def ground_max_near(grid: np.ndarray, xy: np.ndarray, radius: float) -> np.ndarray:
    """Highest ground within ``radius`` (a 3 x 3 stencil) around each point.

    Args:
        grid: (N, 17, 11) from ``scan_grid``.
        xy: (N, K, 2) query points.
        radius: m, half-width of the stencil.
    Returns:
        (N, K) heights.
    """
    best = ground_at(grid, xy)
    for dx in (-radius, 0.0, radius):
        for dy in (-radius, 0.0, radius):
            if dx or dy:
                best = np.maximum(best, ground_at(grid, xy + np.array([dx, dy])))
    return best


def ground_max_along(grid: np.ndarray, start: np.ndarray, end: np.ndarray,
                     samples: int = 6, radius: float = 0.04) -> np.ndarray:
    """Highest ground on the segments ``start -> end`` (both (N, K, 2)), widened by
    ``radius`` across the path; returns (N, K)."""
    best = np.full(start.shape[:2], -np.inf)
    for t in np.linspace(0.0, 1.0, samples):
        p = start + t * (end - start)
        best = np.maximum(best, ground_max_near(grid, p, radius))
    return best


def body_reference(grid: np.ndarray, half_x: float = 0.3, half_y: float = 0.2) -> np.ndarray:
    """Mean ground height under the body footprint (|x| <= half_x, |y| <= half_y): (N,)."""
    xs = np.abs(np.asarray(HEIGHT_SCAN_X)) <= half_x + 1e-9
    ys = np.abs(np.asarray(HEIGHT_SCAN_Y)) <= half_y + 1e-9
    return grid[:, xs][:, :, ys].mean(axis=(1, 2))


__all__ = ["body_reference", "ground_at", "ground_max_along", "ground_max_near", "scan_grid"]
