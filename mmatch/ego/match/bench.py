"""RM-net speed and dense-traffic benchmark for `mmatch bench` (suite "rmnet").

- inference: ONNX Runtime time of the shipped model on graphs of 6, 20 and 40 vehicles a
  side (one thread), median of repeated calls;
- dense traffic: synthetic frame pairs of about 40 vehicles a view (synthetic.py) through
  the Ego path (codec, matching, alignment, confidence) with the default matcher (which hands
  frames this dense to RM-net's search): latency median / p90, success and pair F1.
"""

from __future__ import annotations

import time

import numpy as np

from mmatch.ego.match.synthetic import dense_pair


def inference_ms(sizes=(6, 20, 40), repeats: int = 300) -> dict:
    """Median ms of one ONNX Runtime call of the shipped model at each size (vehicles a side)."""
    from mmatch.ego.match.graph import build_graph
    from mmatch.ego.match.rmnet_runtime import RMNetSession

    sess = RMNetSession()
    out = {}
    own, other, _, _ = dense_pair(31, 45)
    for n in sizes:
        a, b = _subset(own, n), _subset(other, n)
        g = build_graph(a, b)
        for _ in range(20):
            sess.run_graph(g)
        times = []
        for _ in range(repeats):
            t0 = time.perf_counter()
            sess.run_graph(g)
            times.append(time.perf_counter() - t0)
        out[f"inference_ms_{a.num_vehicles}x{b.num_vehicles}"] = round(float(np.median(times)) * 1e3, 3)
    return out


def _subset(frame, n: int):
    """The first n vehicles of a shared frame (vehicles repeated, shifted 8 m, when it has fewer)."""
    from dataclasses import replace

    V = frame.num_vehicles
    if V >= n:
        keep = np.arange(n)
        m = np.isin(frame.vehicle_index, keep)
        return replace(frame, vehicle_points=frame.vehicle_points[m], vehicle_index=frame.vehicle_index[m],
                       vehicle_boxes=frame.vehicle_boxes[keep], vehicle_box_index=frame.vehicle_box_index[keep],
                       vehicle_centers=frame.vehicle_centers[keep], vehicle_features=frame.vehicle_features[keep])
    reps = -(-n // V)
    pts = np.vstack([frame.vehicle_points + np.array([8.0 * k, 0, 0, 0, 0], np.float32) for k in range(reps)])
    idx = np.concatenate([frame.vehicle_index + k * V for k in range(reps)])
    cen = np.vstack([frame.vehicle_centers + np.array([8.0 * k, 0], np.float32) for k in range(reps)])
    big = replace(frame, vehicle_points=pts, vehicle_index=idx.astype(np.int32),
                  vehicle_boxes=np.tile(frame.vehicle_boxes, (reps, 1)),
                  vehicle_box_index=np.arange(V * reps, dtype=np.int32), vehicle_centers=cen,
                  vehicle_features=np.tile(frame.vehicle_features, (reps, 1)))
    return _subset(big, n)


def dense(n: int, per_view: int = 40, seed: int = 41, matcher: str | None = None) -> dict:
    """Ego-path latency, success and pair F1 on n synthetic dense frame pairs (see the module docstring)."""
    from mmatch.codec import decode, encode
    from mmatch.ego.base import MatchContext
    from mmatch.ego.registry import DEFAULT_MATCHER
    from mmatch.fusion import FusionConfig, Fuser
    from mmatch.metrics import is_success, pair_counts, rre_deg, rte_m

    fuser = Fuser(FusionConfig(matcher=matcher or DEFAULT_MATCHER))
    pairs = [dense_pair(seed * 1000 + i, per_view) for i in range(n + 1)]
    totals, cpu, ok, per = [], [], [], []
    tp = pred = gt_n = 0
    for k, (own, other, gt, T) in enumerate(pairs):
        t0, c0 = time.perf_counter(), time.thread_time()
        got = decode(encode(other))
        res = fuser.fuse(own, got, MatchContext(descriptor_scale=1.0))
        ms, cpu_ms = (time.perf_counter() - t0) * 1e3, (time.thread_time() - c0) * 1e3
        if k == 0:
            continue                                        # warm-up
        totals.append(ms)
        cpu.append(cpu_ms)
        per.append(min(own.num_vehicles, other.num_vehicles))
        ok.append(res.T_ego_cav is not None and is_success(rre_deg(T, res.T_ego_cav), rte_m(T, res.T_ego_cav)))
        a, b, c = pair_counts(res.pairs, gt)
        tp, pred, gt_n = tp + a, pred + b, gt_n + c
    p, rc = (tp / pred if pred else 0.0), (tp / gt_n if gt_n else 0.0)
    return {"dense_frame_pairs": n, "dense_matcher": fuser.config.matcher,
            "dense_vehicles_per_view_median": float(np.median(per)),
            "dense_ego_path_ms_median": round(float(np.median(totals)), 2),
            "dense_ego_path_ms_p90": round(float(np.percentile(totals, 90)), 2),
            "dense_ego_path_cpu_ms_median": round(float(np.median(cpu)), 2),     # the same work, CPU time
            "dense_ego_path_cpu_ms_p90": round(float(np.percentile(cpu, 90)), 2),
            "dense_success": round(float(np.mean(ok)), 3),
            "dense_pair_f1": round(2 * p * rc / (p + rc), 3) if p + rc else 0.0}


def run(quick: bool = False) -> dict:
    """Inference ms at 6 / 20 / 40 vehicles a side and the dense-traffic figures."""
    out = inference_ms(repeats=30 if quick else 300)
    out.update(dense(3 if quick else 40))
    return out
