"""Reading and writing `mmatch-scene/1` and `mmatch-radar/1` files (DESIGN.md).

Readers validate every key (presence, dtype kind, shape, finiteness) and raise
`SceneFormatError` naming the file and the key; they never return half-checked data. The
geometry must be a camera and rigid motions (geometry_checks.py, the camera calibration
loader's checks): K a pinhole matrix (last row 0, 0, 1, positive focal lengths, a horizontal
field of view of 5-175 deg), `V_T_cam_radar` and `gt_T_ego_cav` rotations (orthonormal within
1e-3, det +1) with a last row 0, 0, 0, 1. A zero focal length used to be read and gave "no
vehicles" without a word; a scaled or mirrored transform would have been read as a pose.
Value ranges the pipeline copes with (scores, depths, descriptors as another producer may
give them) are not refused here.
"""

from __future__ import annotations

import json
import zipfile
from pathlib import Path

import numpy as np

from mmatch.errors import SceneFormatError
from mmatch.geometry_checks import pinhole_problem, rigid_problem
from mmatch.types import DESCRIPTOR_DIM, CameraModel, Scene, View

SCENE_FORMAT = "mmatch-scene/1"
RADAR_FORMAT = "mmatch-radar/1"


class _Reader:
    """Checked access to the arrays of one npz file."""

    def __init__(self, path: Path, data) -> None:
        self.path = str(path)
        self.data = data

    def fail(self, key: str, reason: str) -> SceneFormatError:
        return SceneFormatError(self.path, key, reason)

    def get(self, key: str, kind: str, shape: tuple, optional: bool = False,
            finite: bool = True) -> np.ndarray | None:
        """Fetch `key`; kind is 'f' (float), 'i' (integer), 'b' (bool) or 'U' (str).

        shape uses None for a free dimension; a str entry ties dims across keys by name.
        """
        if key not in self.data.files:
            if optional:
                return None
            raise self.fail(key, "missing")
        try:
            arr = self.data[key]
        except (ValueError, OSError, zipfile.BadZipFile, EOFError) as exc:
            raise self.fail(key, f"unreadable ({exc})") from exc
        ok_kind = {"f": "f", "i": "iu", "b": "b", "U": "US"}[kind]
        if arr.dtype.kind not in ok_kind:
            raise self.fail(key, f"dtype {arr.dtype} is not {'float' if kind == 'f' else kind}")
        if arr.ndim != len(shape) or any(s is not None and s != d for s, d in zip(shape, arr.shape)):
            want = "(" + ", ".join("N" if s is None else str(s) for s in shape) + ")"
            raise self.fail(key, f"shape {arr.shape} is not {want}")
        if finite and kind == "f" and not np.all(np.isfinite(arr)):
            raise self.fail(key, "contains NaN or infinity")
        return arr


def _check(r: _Reader, key: str, problem: str | None) -> None:
    if problem is not None:
        raise r.fail(key, problem)


def _read_view(r: _Reader, v: str) -> View:
    points = r.get(f"{v}_points", "f", (None, 5)).astype(np.float32)
    boxes = r.get(f"{v}_boxes", "f", (None, 6)).astype(np.float32)
    features = r.get(f"{v}_features", "f", (None, DESCRIPTOR_DIM)).astype(np.float32)
    if len(features) != len(boxes):
        raise r.fail(f"{v}_features", f"{len(features)} rows for {len(boxes)} boxes")
    K = r.get(f"{v}_K", "f", (3, 3)).astype(np.float64)
    size = r.get(f"{v}_image_size", "i", (2,))
    if np.any(size <= 0):
        raise r.fail(f"{v}_image_size", f"non-positive size {size.tolist()}")
    _check(r, f"{v}_K", pinhole_problem(K, int(size[0])))
    T = r.get(f"{v}_T_cam_radar", "f", (4, 4)).astype(np.float64)
    _check(r, f"{v}_T_cam_radar", rigid_problem(T))
    stamp = float(r.get(f"{v}_stamp", "f", ()))
    height = float(r.get(f"{v}_radar_height", "f", ()))
    labels = r.get(f"{v}_point_labels", "i", (len(points),), optional=True)
    box_ids = r.get(f"{v}_box_ids", "i", (len(boxes),), optional=True)
    return View(points=points, boxes=boxes, features=features,
                camera=CameraModel(K=K, image_size=(int(size[0]), int(size[1])), T_cam_radar=T),
                stamp=stamp, radar_height=height,
                point_labels=None if labels is None else labels.astype(np.int32),
                box_ids=None if box_ids is None else box_ids.astype(np.int32))


def _open(path: Path):
    try:
        return np.load(path, allow_pickle=False)
    except (OSError, ValueError, zipfile.BadZipFile, EOFError) as exc:
        raise SceneFormatError(str(path), "<file>", f"not a readable npz ({exc})") from exc


def load_scene(path: str | Path) -> Scene:
    """Read and validate one `mmatch-scene/1` file; raise SceneFormatError naming the key."""
    path = Path(path)
    with _open(path) as data:
        r = _Reader(path, data)
        fmt = r.get("format", "U", ())
        if str(fmt) != SCENE_FORMAT:
            raise r.fail("format", f"{str(fmt)!r} is not {SCENE_FORMAT!r}")
        ego = _read_view(r, "ego")
        cav = _read_view(r, "cav")
        T = r.get("gt_T_ego_cav", "f", (4, 4)).astype(np.float64)
        _check(r, "gt_T_ego_cav", rigid_problem(T))
        pairs = r.get("gt_pairs", "i", (None, 2)).astype(np.int32)
        if len(pairs) and (pairs[:, 0].min() < 0 or pairs[:, 0].max() >= len(ego.boxes)
                           or pairs[:, 1].min() < 0 or pairs[:, 1].max() >= len(cav.boxes)):
            raise r.fail("gt_pairs", "box index out of range")
        meta_arr = r.get("meta", "U", (), optional=True)
        meta = {}
        if meta_arr is not None:
            try:
                meta = json.loads(str(meta_arr))
            except json.JSONDecodeError as exc:
                raise r.fail("meta", f"not JSON ({exc})") from exc
    return Scene(ego=ego, cav=cav, gt_T_ego_cav=T, gt_pairs=pairs, meta=meta, name=path.stem)


def scene_arrays(scene: Scene) -> dict[str, np.ndarray]:
    """The npz key -> array mapping of a scene, with the dtypes of DESIGN.md."""
    out: dict[str, np.ndarray] = {"format": np.array(SCENE_FORMAT)}
    for v, view in (("ego", scene.ego), ("cav", scene.cav)):
        out[f"{v}_points"] = np.asarray(view.points, np.float32).reshape(-1, 5)
        out[f"{v}_boxes"] = np.asarray(view.boxes, np.float32).reshape(-1, 6)
        out[f"{v}_features"] = np.asarray(view.features, np.float32).reshape(-1, DESCRIPTOR_DIM)
        out[f"{v}_K"] = np.asarray(view.camera.K, np.float64)
        out[f"{v}_image_size"] = np.asarray(view.camera.image_size, np.int32)
        out[f"{v}_T_cam_radar"] = np.asarray(view.camera.T_cam_radar, np.float64)
        out[f"{v}_stamp"] = np.float64(view.stamp)
        out[f"{v}_radar_height"] = np.float64(view.radar_height)
        if view.point_labels is not None:
            out[f"{v}_point_labels"] = np.asarray(view.point_labels, np.int32)
        if view.box_ids is not None:
            out[f"{v}_box_ids"] = np.asarray(view.box_ids, np.int32)
    out["gt_T_ego_cav"] = np.asarray(scene.gt_T_ego_cav, np.float64)
    out["gt_pairs"] = np.asarray(scene.gt_pairs, np.int32).reshape(-1, 2)
    if scene.meta:
        out["meta"] = np.array(json.dumps(scene.meta))
    return out


def save_scene(path: str | Path, scene: Scene) -> None:
    """Write a scene as a compressed `mmatch-scene/1` npz."""
    with open(path, "wb") as f:
        np.savez_compressed(f, **scene_arrays(scene))


def load_radar_frame(path: str | Path) -> dict:
    """Read one `mmatch-radar/1` file: {'points', 'gt_velocity' or None, 'gt_moving' or None}."""
    path = Path(path)
    with _open(path) as data:
        r = _Reader(path, data)
        fmt = r.get("format", "U", ())
        if str(fmt) != RADAR_FORMAT:
            raise r.fail("format", f"{str(fmt)!r} is not {RADAR_FORMAT!r}")
        points = r.get("points", "f", (None, 5)).astype(np.float32)
        vel = r.get("gt_velocity", "f", (2,), optional=True)
        moving = r.get("gt_moving", "b", (len(points),), optional=True)
    return {"points": points,
            "gt_velocity": None if vel is None else vel.astype(np.float64),
            "gt_moving": moving}


def save_radar_frame(path: str | Path, points: np.ndarray, gt_velocity: np.ndarray | None = None,
                     gt_moving: np.ndarray | None = None) -> None:
    """Write one `mmatch-radar/1` npz."""
    arrays = {"format": np.array(RADAR_FORMAT), "points": np.asarray(points, np.float32)}
    if gt_velocity is not None:
        arrays["gt_velocity"] = np.asarray(gt_velocity, np.float64)
    if gt_moving is not None:
        arrays["gt_moving"] = np.asarray(gt_moving, bool)
    with open(path, "wb") as f:
        np.savez_compressed(f, **arrays)
