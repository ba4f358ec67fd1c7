"""What makes a matrix a pinhole camera's intrinsics or a rigid motion: the checks shared by the
scene reader (scene_io.py) and the camera calibration loader (drivers/camera/calibration.py).
Each returns None for a valid matrix, else the reason in words."""

from __future__ import annotations

import numpy as np


def rigid_problem(T: np.ndarray) -> str | None:
    """Why a finite (4, 4) T is not a rotation and a translation (last row 0, 0, 0, 1; rotation
    orthonormal within 1e-3, det +1), or None."""
    if not np.allclose(T[3], (0.0, 0.0, 0.0, 1.0), atol=1e-9):
        return f"last row must be [0, 0, 0, 1], got {T[3].tolist()}"
    R = T[:3, :3]
    err = float(np.abs(R.T @ R - np.eye(3)).max())
    if err > 1e-3:
        return f"rotation is not orthonormal (max |R^T R - I| = {err:.2e})"
    if np.linalg.det(R) < 0:
        return "rotation has det -1 (a reflection; check axis signs)"
    return None


def pinhole_problem(K: np.ndarray, width: int) -> str | None:
    """Why a finite (3, 3) K is not a pinhole camera's for an image `width` px wide (last row
    0, 0, 1; positive focal lengths; a horizontal field of view of 5-175 deg), or None."""
    if not np.allclose(K[2], (0.0, 0.0, 1.0), atol=1e-9):
        return f"last row must be [0, 0, 1], got {K[2].tolist()}"
    fx, fy = float(K[0, 0]), float(K[1, 1])
    if fx <= 0 or fy <= 0:
        return f"focal lengths must be positive (fx={fx:g}, fy={fy:g})"
    hfov = float(np.degrees(2 * np.arctan(width / (2 * fx))))
    if not 5.0 <= hfov <= 175.0:
        return (f"fx={fx:g} px gives a horizontal field of view of {hfov:.1f} deg for width {width} px; "
                f"expected 5..175 deg (focal length in px?)")
    return None
