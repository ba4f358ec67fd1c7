"""Camera calibration file (TOML): intrinsics, distortion, image size, radar->camera extrinsic.

Format `mmatch-camera-calibration/1` (see cfg/camera/example_calibration.toml):

    format = "mmatch-camera-calibration/1"
    [camera]
    image_size = [1280, 720]                 # width, height (px)
    K = [[fx, 0, cx], [0, fy, cy], [0, 0, 1]] # px
    dist = [k1, k2, p1, p2, k3]              # OpenCV order; 0, 4, 5, 8, 12 or 14 values
    [extrinsic]
    T_cam_radar = [[...], [...], [...], [0, 0, 0, 1]]   # radar -> OpenCV camera frame, m
    [ground]                                 # optional: for ground-plane depth
    camera_height = 1.45                     # m above the road
    pitch_deg = 2.0                          # positive = looking down
    roll_deg = 0.0

Validation (errors name the file and the key): shapes, finite values, K[2] = (0, 0, 1),
focal lengths positive with a horizontal field of view between 5 and 175 degrees and an
aspect fx/fy within [0.5, 2], principal point inside the image, rotation of T_cam_radar
orthonormal (|R^T R - I| < 1e-3) with det +1, last row (0, 0, 0, 1), translation < 10 m.
"""

from __future__ import annotations

import tomllib
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from mmatch.drivers.camera.depth import GroundPlane
from mmatch.drivers.camera.errors import CalibrationError
from mmatch.errors import MMatchError
from mmatch.geometry_checks import pinhole_problem, rigid_problem
from mmatch.types import CameraModel

FORMAT = "mmatch-camera-calibration/1"
_DIST_LENGTHS = (0, 4, 5, 8, 12, 14)


class EstimationError(MMatchError, ValueError):
    """Too few or degenerate pairs to estimate an extrinsic."""


@dataclass(frozen=True)
class Calibration:
    """A validated camera calibration.

    K: float64 (3, 3) px; dist: float64 (D,) OpenCV distortion; image_size: (width, height) px;
    T_cam_radar: float64 (4, 4) radar -> camera (OpenCV frame), m; ground: optional road plane.
    """

    K: np.ndarray
    dist: np.ndarray
    image_size: tuple[int, int]
    T_cam_radar: np.ndarray
    ground: GroundPlane | None = None
    source: str = "<memory>"

    def camera_model(self) -> CameraModel:
        """The pinhole model the pipeline uses (boxes leave the driver undistorted)."""
        return CameraModel(
            K=self.K.copy(), image_size=tuple(self.image_size), T_cam_radar=self.T_cam_radar.copy()
        )

    def ground_plane(self, radar_height: float | None = None) -> GroundPlane | None:
        """The [ground] table, else derived from T_cam_radar and the radar height (if given)."""
        if self.ground is not None:
            return self.ground
        if radar_height is not None:
            return GroundPlane.from_extrinsic(self.T_cam_radar, radar_height)
        return None

    def undistort_points(self, uv: np.ndarray) -> np.ndarray:
        """(N, 2) distorted pixels -> (N, 2) ideal pinhole pixels (same K)."""
        uv = np.asarray(uv, np.float64).reshape(-1, 2)
        if len(uv) == 0 or not np.any(self.dist):
            return uv.copy()
        import cv2

        out = cv2.undistortPoints(uv[:, None, :], self.K, self.dist, P=self.K)
        return out.reshape(-1, 2)

    def undistort_boxes(self, boxes: np.ndarray) -> np.ndarray:
        """Boxes (M, >=4) u1, v1, u2, v2 in the distorted image -> the axis-aligned box around
        their undistorted outline (other columns copied). float32 (M, same columns).

        The straight edges of a box in the distorted image are curves after undistortion; the
        outline is sampled at 5 points per edge plus where the edges cross the principal
        axes (where a radially distorted edge bulges most)."""
        b = np.asarray(boxes, np.float32)
        out = b.copy()
        if len(b) == 0 or not np.any(self.dist):
            return out
        u1, v1, u2, v2 = (b[:, i].astype(np.float64)[:, None] for i in range(4))
        t = np.linspace(0.0, 1.0, 5)[None, :]
        cu = np.clip(self.K[0, 2], u1, u2)  # principal-axis crossings, clipped to the box
        cv = np.clip(self.K[1, 2], v1, v2)
        us = np.concatenate([u1 + (u2 - u1) * t, cu], axis=1)  # (M, 6) along horizontal edges
        vs = np.concatenate([v1 + (v2 - v1) * t, cv], axis=1)  # (M, 6) along vertical edges
        n = us.shape[1]
        pts = np.concatenate(
            [
                np.stack([us, np.repeat(v1, n, 1)], -1),
                np.stack([us, np.repeat(v2, n, 1)], -1),
                np.stack([np.repeat(u1, n, 1), vs], -1),
                np.stack([np.repeat(u2, n, 1), vs], -1),
            ],
            axis=1,
        )  # (M, 4n, 2)
        und = self.undistort_points(pts.reshape(-1, 2)).reshape(len(b), -1, 2)
        out[:, 0:2] = und.min(axis=1)
        out[:, 2:4] = und.max(axis=1)
        return out


def _matrix(path: str, key: str, value, shape: tuple[int, ...]) -> np.ndarray:
    try:
        a = np.asarray(value, dtype=np.float64)
    except (TypeError, ValueError) as exc:
        raise CalibrationError(path, key, f"expected a numeric array of shape {shape}") from exc
    if a.shape != shape:
        raise CalibrationError(path, key, f"expected shape {shape}, got {a.shape}")
    if not np.isfinite(a).all():
        raise CalibrationError(path, key, "contains a non-finite value")
    return a


def validate(
    K, dist, image_size, T_cam_radar, ground: dict | None = None, path: str = "<memory>"
) -> Calibration:
    """Check every field (see module docstring) and build a Calibration; errors name the key."""
    try:
        size = tuple(int(x) for x in image_size)
    except (TypeError, ValueError) as exc:
        raise CalibrationError(
            path, "camera.image_size", "expected [width, height] integers"
        ) from exc
    if len(size) != 2 or min(size) < 16 or max(size) > 16384:
        raise CalibrationError(
            path, "camera.image_size", f"expected [width, height] in 16..16384 px, got {image_size}"
        )
    W, H = size
    K = _matrix(path, "camera.K", K, (3, 3))
    if not np.allclose(K[2], (0, 0, 1)) or K[1, 0] != 0:
        raise CalibrationError(
            path, "camera.K", f"expected [[fx, s, cx], [0, fy, cy], [0, 0, 1]], got {K.tolist()}"
        )
    fx, fy, cx, cy = K[0, 0], K[1, 1], K[0, 2], K[1, 2]
    problem = pinhole_problem(K, W)
    if problem is not None:
        raise CalibrationError(path, "camera.K", problem)
    if not 0.5 <= fx / fy <= 2.0:
        raise CalibrationError(path, "camera.K", f"fx/fy = {fx / fy:.3f} outside [0.5, 2]")
    if not (0 <= cx <= W and 0 <= cy <= H):
        raise CalibrationError(
            path, "camera.K", f"principal point ({cx:g}, {cy:g}) outside the {W}x{H} image"
        )
    d = np.asarray(dist if dist is not None else [], dtype=np.float64).ravel()
    if d.size not in _DIST_LENGTHS:
        raise CalibrationError(
            path,
            "camera.dist",
            f"expected {', '.join(map(str, _DIST_LENGTHS))} coefficients "
            f"(OpenCV order k1, k2, p1, p2[, k3...]), got {d.size}",
        )
    if not np.isfinite(d).all():
        raise CalibrationError(path, "camera.dist", "contains a non-finite value")
    T = _matrix(path, "extrinsic.T_cam_radar", T_cam_radar, (4, 4))
    problem = rigid_problem(T)
    if problem is not None:
        raise CalibrationError(path, "extrinsic.T_cam_radar", problem)
    if np.linalg.norm(T[:3, 3]) > 10.0:
        raise CalibrationError(
            path, "extrinsic.T_cam_radar", f"translation {T[:3, 3].tolist()} is over 10 m (units?)"
        )
    gp = None
    if ground is not None:
        unknown = sorted(set(ground) - {"camera_height", "pitch_deg", "roll_deg"})
        if unknown:
            raise CalibrationError(
                path,
                f"ground.{unknown[0]}",
                "unknown key (known: camera_height, pitch_deg, roll_deg)",
            )
        if "camera_height" not in ground:
            raise CalibrationError(path, "ground.camera_height", "missing")
        h = ground["camera_height"]
        if not isinstance(h, (int, float)) or not 0.1 <= h <= 10.0:
            raise CalibrationError(
                path, "ground.camera_height", f"expected metres in 0.1..10, got {h!r}"
            )
        for key in ("pitch_deg", "roll_deg"):
            val = ground.get(key, 0.0)
            if not isinstance(val, (int, float)) or not -45.0 <= val <= 45.0:
                raise CalibrationError(
                    path, f"ground.{key}", f"expected degrees in -45..45, got {val!r}"
                )
        gp = GroundPlane(
            float(h), float(ground.get("pitch_deg", 0.0)), float(ground.get("roll_deg", 0.0))
        )
    return Calibration(K=K, dist=d, image_size=(W, H), T_cam_radar=T, ground=gp, source=path)


def load_calibration(path: str | Path) -> Calibration:
    """Read and validate a calibration TOML file (format `mmatch-camera-calibration/1`)."""
    p = str(path)
    try:
        with open(path, "rb") as f:
            data = tomllib.load(f)
    except FileNotFoundError as exc:
        raise CalibrationError(p, "(file)", "no such file") from exc
    except tomllib.TOMLDecodeError as exc:
        raise CalibrationError(p, "(file)", f"not valid TOML: {exc}") from exc
    if data.get("format") != FORMAT:
        raise CalibrationError(p, "format", f"expected {FORMAT!r}, got {data.get('format')!r}")
    unknown = sorted(set(data) - {"format", "camera", "extrinsic", "ground"})
    if unknown:
        raise CalibrationError(p, unknown[0], "unknown table (known: camera, extrinsic, ground)")
    cam, ext = data.get("camera"), data.get("extrinsic")
    if not isinstance(cam, dict):
        raise CalibrationError(p, "camera", "missing table [camera]")
    if not isinstance(ext, dict):
        raise CalibrationError(p, "extrinsic", "missing table [extrinsic]")
    for key in ("image_size", "K"):
        if key not in cam:
            raise CalibrationError(p, f"camera.{key}", "missing")
    unknown = sorted(set(cam) - {"image_size", "K", "dist"})
    if unknown:
        raise CalibrationError(
            p, f"camera.{unknown[0]}", "unknown key (known: image_size, K, dist)"
        )
    if "T_cam_radar" not in ext:
        raise CalibrationError(p, "extrinsic.T_cam_radar", "missing")
    return validate(
        cam["K"], cam.get("dist", []), cam["image_size"], ext["T_cam_radar"], data.get("ground"), p
    )


def _fmt_rows(a: np.ndarray) -> str:
    a = np.atleast_2d(a)
    return "[" + ", ".join("[" + ", ".join(repr(float(x)) for x in row) + "]" for row in a) + "]"


def dumps_calibration(c: Calibration) -> str:
    """TOML text of a calibration (round-trips through load_calibration)."""
    lines = [
        f'format = "{FORMAT}"',
        "",
        "[camera]",
        f"image_size = [{c.image_size[0]}, {c.image_size[1]}]",
        f"K = {_fmt_rows(c.K)}",
        "dist = [" + ", ".join(repr(float(x)) for x in c.dist) + "]",
        "",
        "[extrinsic]",
        f"T_cam_radar = {_fmt_rows(c.T_cam_radar)}",
    ]
    if c.ground is not None:
        lines += [
            "",
            "[ground]",
            f"camera_height = {c.ground.camera_height!r}",
            f"pitch_deg = {c.ground.pitch_deg!r}",
            f"roll_deg = {c.ground.roll_deg!r}",
        ]
    return "\n".join(lines) + "\n"


def save_calibration(path: str | Path, c: Calibration) -> None:
    Path(path).write_text(dumps_calibration(c))


def project_radar(points_radar: np.ndarray, K: np.ndarray, T_cam_radar: np.ndarray) -> np.ndarray:
    """(N, 3) radar-frame points -> (N, 2) ideal pixels (NaN behind the camera)."""
    p = np.asarray(points_radar, np.float64)[:, :3] @ T_cam_radar[:3, :3].T + T_cam_radar[:3, 3]
    with np.errstate(divide="ignore", invalid="ignore"):
        uv = (p @ np.asarray(K, np.float64).T)[:, :2] / p[:, 2:3]
    uv[p[:, 2] <= 1e-6] = np.nan
    return uv


def estimate_T_cam_radar(
    points_radar: np.ndarray,
    pixels: np.ndarray,
    K: np.ndarray,
    dist: np.ndarray | None = None,
    T_init: np.ndarray | None = None,
    reprojection_px: float = 8.0,
    iterations: int = 500,
) -> tuple[np.ndarray, dict]:
    """Estimate the radar->camera extrinsic from matched radar/box pairs of a recording.

    points_radar: (N, 3) radar-frame positions (m) of vehicles (e.g. the centroid of each
        vehicle's radar cluster); pixels: (N, 2) the matching image points (px, distorted as
        recorded; e.g. the box centre). N >= 6, spread over range and azimuth.
    T_init: optional initial guess (4, 4) (e.g. the nominal mounting); strongly recommended
        because radar points lie close to one plane.
    RANSAC (OpenCV solvePnPRansac, `reprojection_px` inlier threshold) then Levenberg-Marquardt
    refinement on the inliers. Returns (T_cam_radar float64 (4, 4), info) with info keys
    "rms_px" (inlier reprojection RMS), "inliers" (int array of indices), "n".
    Raises EstimationError when there are too few pairs or no consistent solution.
    """
    import cv2

    obj = np.asarray(points_radar, np.float64).reshape(-1, 3)
    img = np.asarray(pixels, np.float64).reshape(-1, 2)
    if len(obj) != len(img):
        raise EstimationError(f"{len(obj)} radar points but {len(img)} pixels")
    ok = np.isfinite(obj).all(1) & np.isfinite(img).all(1)
    obj, img = obj[ok], img[ok]
    if len(obj) < 6:
        raise EstimationError(f"need at least 6 finite radar/box pairs, got {len(obj)}")
    K = np.asarray(K, np.float64)
    d = np.zeros(5) if dist is None else np.asarray(dist, np.float64)
    if T_init is not None:
        rvec0, _ = cv2.Rodrigues(np.asarray(T_init, np.float64)[:3, :3])
        tvec0 = np.asarray(T_init, np.float64)[:3, 3].reshape(3, 1).copy()
        found, rvec, tvec, inl = cv2.solvePnPRansac(
            obj,
            img,
            K,
            d,
            rvec0.copy(),
            tvec0.copy(),
            True,
            iterations,
            reprojection_px,
            0.999,
            None,
            cv2.SOLVEPNP_ITERATIVE,
        )
    else:
        found, rvec, tvec, inl = cv2.solvePnPRansac(
            obj,
            img,
            K,
            d,
            None,
            None,
            False,
            iterations,
            reprojection_px,
            0.999,
            None,
            cv2.SOLVEPNP_SQPNP,
        )
    if not found or inl is None or len(inl) < 6:
        raise EstimationError(
            f"no consistent extrinsic from {len(obj)} pairs "
            f"({0 if inl is None else len(inl)} inliers at {reprojection_px} px)"
        )
    inl = inl.ravel()
    rvec, tvec = cv2.solvePnPRefineLM(obj[inl], img[inl], K, d, rvec, tvec)
    R, _ = cv2.Rodrigues(rvec)
    T = np.eye(4)
    T[:3, :3], T[:3, 3] = R, tvec.ravel()
    proj, _ = cv2.projectPoints(obj[inl], rvec, tvec, K, d)
    rms = float(np.sqrt(np.mean(np.sum((proj.reshape(-1, 2) - img[inl]) ** 2, axis=1))))
    return T, {"rms_px": rms, "inliers": np.flatnonzero(ok)[inl], "n": int(len(obj))}


def collect_pairs(
    frames: list[tuple[np.ndarray, np.ndarray]],
    K: np.ndarray,
    T_guess: np.ndarray,
    dist: np.ndarray | None = None,
    max_px: float = 80.0,
) -> tuple[np.ndarray, np.ndarray]:
    """Unambiguous radar/box pairs of a recording, under an approximate extrinsic.

    frames: per frame, (centroids (K, 3) radar-frame vehicle positions, m; boxes (M, >=4) px as
        detected). A pair is kept when the centroid's projection (with `T_guess`) and the box
        centre are each other's nearest, within `max_px`, and the second-nearest candidate is
        at least twice as far on both sides (crowded frames give no pair).
    Returns (points (P, 3), pixels (P, 2)) for `estimate_T_cam_radar`.
    """
    import cv2

    pts_out, px_out = [], []
    d = np.zeros(5) if dist is None else np.asarray(dist, np.float64)
    R, t = np.asarray(T_guess, np.float64)[:3, :3], np.asarray(T_guess, np.float64)[:3, 3]
    rvec, _ = cv2.Rodrigues(R)
    for centroids, boxes in frames:
        c = np.asarray(centroids, np.float64).reshape(-1, 3)
        b = np.asarray(boxes, np.float64)
        if len(c) == 0 or b.size == 0:
            continue
        b = b.reshape(len(b), -1)
        front = (c @ R.T + t)[:, 2] > 0.5
        c = c[front]
        if len(c) == 0:
            continue
        proj, _ = cv2.projectPoints(c, rvec, t, K, d)
        proj = proj.reshape(-1, 2)
        centres = np.stack([(b[:, 0] + b[:, 2]) / 2, (b[:, 1] + b[:, 3]) / 2], 1)
        dm = np.linalg.norm(proj[:, None] - centres[None], axis=2)  # (K, M)
        best_box = dm.argmin(1)
        best_pt = dm.argmin(0)
        for i, j in enumerate(best_box):
            if best_pt[j] != i or dm[i, j] > max_px:
                continue
            row = np.sort(dm[i])
            col = np.sort(dm[:, j])
            if (len(row) > 1 and row[1] < 2 * row[0]) or (len(col) > 1 and col[1] < 2 * col[0]):
                continue
            pts_out.append(c[i])
            px_out.append(centres[j])
    if not pts_out:
        return np.zeros((0, 3)), np.zeros((0, 2))
    return np.asarray(pts_out), np.asarray(px_out)


def estimate_T_cam_radar_from_recording(
    frames: list[tuple[np.ndarray, np.ndarray]],
    K: np.ndarray,
    T_guess: np.ndarray,
    dist: np.ndarray | None = None,
    max_px: float = 80.0,
    rounds: int = 3,
) -> tuple[np.ndarray, dict]:
    """Alternate pairing (`collect_pairs`) and estimation (`estimate_T_cam_radar`), narrowing
    the pairing gate each round (max_px, max_px / 2, ... down to 10 px). Starts from the
    nominal mounting `T_guess`; returns (T_cam_radar, info) of the last round, with
    info["pairs"] the number of pairs used."""
    T = np.asarray(T_guess, np.float64)
    info: dict = {}
    gate = max_px
    for _ in range(max(1, rounds)):
        pts, px = collect_pairs(frames, K, T, dist, gate)
        T, info = estimate_T_cam_radar(
            pts, px, K, dist, T_init=T, reprojection_px=max(gate / 4, 4.0)
        )
        info["pairs"] = int(len(pts))
        gate = max(gate / 2, 10.0)
    return T, info
