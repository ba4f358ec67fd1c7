"""Accuracy metrics of DESIGN.md: RRE, RTE, success, co-visible pair precision and recall, and
how well confidences say how often estimates are right (`reliability`)."""

from __future__ import annotations

import numpy as np

SUCCESS_RRE_DEG = 5.0
SUCCESS_RTE_M = 2.0


def euler_zyx(R: np.ndarray) -> np.ndarray:
    """Euler angles (roll, pitch, yaw) in rad of a rotation matrix (ZYX convention)."""
    pitch = np.arcsin(np.clip(-R[2, 0], -1.0, 1.0))
    roll = np.arctan2(R[2, 1], R[2, 2])
    yaw = np.arctan2(R[1, 0], R[0, 0])
    return np.array([roll, pitch, yaw])


def rre_deg(T_gt: np.ndarray, T_est: np.ndarray) -> float:
    """Relative rotation error: sum of absolute Euler angles of R_gt^T R_est, degrees."""
    return float(np.degrees(np.abs(euler_zyx(T_gt[:3, :3].T @ T_est[:3, :3])).sum()))


def rte_m(T_gt: np.ndarray, T_est: np.ndarray) -> float:
    """Relative translation error ||t_gt - t_est||, metres."""
    return float(np.linalg.norm(T_gt[:3, 3] - T_est[:3, 3]))


GROSS_RRE_DEG = 10.0
GROSS_RTE_M = 5.0


def is_success(rre: float, rte: float) -> bool:
    return rre < SUCCESS_RRE_DEG and rte < SUCCESS_RTE_M


def is_gross(rre: float, rte: float) -> bool:
    """A grossly wrong estimate: RRE > 10 deg or RTE > 5 m (DESIGN.md)."""
    return rre > GROSS_RRE_DEG or rte > GROSS_RTE_M


def pair_counts(pred: np.ndarray, gt: np.ndarray) -> tuple[int, int, int]:
    """(true positives, predicted, ground truth) over (own box, other box) index pairs."""
    p = {(int(a), int(b)) for a, b in np.asarray(pred).reshape(-1, 2)}
    g = {(int(a), int(b)) for a, b in np.asarray(gt).reshape(-1, 2)}
    return len(p & g), len(p), len(g)


def summary(values: list[float]) -> dict[str, float]:
    """median / mean / p90 of a list (NaN when empty)."""
    if not values:
        return {"median": float("nan"), "mean": float("nan"), "p90": float("nan")}
    a = np.asarray(values, float)
    return {"median": float(np.median(a)), "mean": float(a.mean()), "p90": float(np.percentile(a, 90))}


def reliability(p: np.ndarray, success: np.ndarray, bins: int = 10) -> dict:
    """How well confidences p (n,) say how often estimates are right (success (n,)): the
    expected calibration error (share-weighted |mean confidence - success rate| over `bins`
    equal-width bins), the Brier score and the bins (lo, hi, n, confidence, success)."""
    p, y = np.asarray(p, float), np.asarray(success, float)
    ok = np.isfinite(p)
    p, y = p[ok], y[ok]
    rows, ece = [], 0.0
    edges = np.linspace(0.0, 1.0, bins + 1)
    k = np.clip(np.searchsorted(edges, p, side="right") - 1, 0, bins - 1)
    for b in range(bins):
        m = k == b
        if m.any():
            rows.append({"lo": float(edges[b]), "hi": float(edges[b + 1]), "n": int(m.sum()),
                         "confidence": float(p[m].mean()), "success": float(y[m].mean())})
            ece += m.mean() * abs(p[m].mean() - y[m].mean())
    return {"ece": float(ece) if len(p) else float("nan"),
            "brier": float(np.mean((p - y) ** 2)) if len(p) else float("nan"), "bins": rows}
