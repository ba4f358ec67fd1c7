"""Training samples for RM-net: simulated scenes -> both views' CAV-side products -> labelled graphs.

A sample is one frame pair as the Ego has it at run time (both views through the real
CAV-side pipeline, `mmatch.cav.process`), its graph (graph.py) and the (Va, Vb) 0/1 target
of which vehicles are the same (from the scene's ground-truth box pairs). Pure numpy: the
scenes are drawn in worker processes; torch only sees the finished arrays.
"""

from __future__ import annotations

from collections.abc import Callable
from concurrent.futures import ProcessPoolExecutor
from dataclasses import dataclass

import numpy as np

from mmatch.ego.match.graph import build_graph
from mmatch.shared import SharedFrame


@dataclass
class Sample:
    """One labelled graph: nodes (V, F), local edges (V, K, Fe) + neighbours (V, K) per view, target (Va, Vb)."""

    xa: np.ndarray
    ea: np.ndarray
    na: np.ndarray
    xb: np.ndarray
    eb: np.ndarray
    nb: np.ndarray
    target: np.ndarray
    name: str = ""

    def swapped(self) -> Sample:
        """The same frame pair seen from the other vehicle (Ego and CAV exchanged)."""
        return Sample(self.xb, self.eb, self.nb, self.xa, self.ea, self.na, self.target.T.copy(), self.name)


def collate_arrays(samples: list[Sample]) -> dict[str, np.ndarray]:
    """Pad samples into batch arrays (fit.py `collate` makes them tensors; the appearance
    augmentation rewrites them first): nodes, edges, neighbours, edge and node masks, targets."""
    B = len(samples)
    Va = max(len(s.xa) for s in samples)
    Vb = max(len(s.xb) for s in samples)
    Ka = max(s.ea.shape[1] for s in samples)
    Kb = max(s.eb.shape[1] for s in samples)
    F, Fe = samples[0].xa.shape[1], samples[0].ea.shape[2]
    out = {"xa": np.zeros((B, Va, F), np.float32), "xb": np.zeros((B, Vb, F), np.float32),
           "ea": np.zeros((B, Va, Ka, Fe), np.float32), "eb": np.zeros((B, Vb, Kb, Fe), np.float32),
           "na": np.zeros((B, Va, Ka), np.int64), "nb": np.zeros((B, Vb, Kb), np.int64),
           "la": np.zeros((B, Va, Ka), np.float32), "lb": np.zeros((B, Vb, Kb), np.float32),
           "ma": np.zeros((B, Va), np.float32), "mb": np.zeros((B, Vb), np.float32),
           "target": np.zeros((B, Va, Vb), np.float32)}
    for k, s in enumerate(samples):
        va, vb, ka, kb = len(s.xa), len(s.xb), s.ea.shape[1], s.eb.shape[1]
        out["xa"][k, :va], out["xb"][k, :vb] = s.xa, s.xb
        out["ea"][k, :va, :ka], out["eb"][k, :vb, :kb] = s.ea, s.eb
        out["na"][k, :va, :ka], out["nb"][k, :vb, :kb] = s.na, s.nb
        out["la"][k, :va, :ka], out["lb"][k, :vb, :kb] = 1, 1
        out["ma"][k, :va], out["mb"][k, :vb] = 1, 1
        out["target"][k, :va, :vb] = s.target
    return out


def target_matrix(own: SharedFrame, other: SharedFrame, gt_box_pairs: np.ndarray) -> np.ndarray:
    """(Va, Vb) float32: 1 where own vehicle i and other vehicle j come from a ground-truth box pair."""
    t = np.zeros((own.num_vehicles, other.num_vehicles), np.float32)
    if len(gt_box_pairs) == 0 or t.size == 0:
        return t
    own_of = {int(b): v for v, b in enumerate(own.vehicle_box_index)}
    other_of = {int(b): v for v, b in enumerate(other.vehicle_box_index)}
    for a, b in np.asarray(gt_box_pairs).reshape(-1, 2):
        if int(a) in own_of and int(b) in other_of:
            t[own_of[int(a)], other_of[int(b)]] = 1.0
    return t


def sample_from_frames(own: SharedFrame, other: SharedFrame, gt_box_pairs: np.ndarray, name: str = "") -> Sample | None:
    """The labelled graph of one frame pair, or None when a view has fewer than 2 vehicles."""
    if own.num_vehicles < 2 or other.num_vehicles < 2:
        return None
    g = build_graph(own, other)
    return Sample(g.own.nodes, g.own.edges, g.own.neighbours, g.other.nodes, g.other.edges, g.other.neighbours,
                  target_matrix(own, other, gt_box_pairs), name)


def _scene_sample(args: tuple) -> Sample | None:
    from mmatch.cav.process import process_view
    from mmatch.sim.scenario import make_scene

    seed, index, mode, physics = args
    scene = make_scene(seed, index, mode, physics)
    e, c = scene.ego, scene.cav
    own, _ = process_view(e.points, e.boxes, e.features, e.camera, e.radar_height, e.stamp, sender="ego")
    other, _ = process_view(c.points, c.boxes, c.features, c.camera, c.radar_height, c.stamp, sender="cav")
    return sample_from_frames(own, other, scene.gt_pairs, scene.name)


def _synthetic_sample(args: tuple[int, int]) -> Sample | None:
    from mmatch.codec import decode, encode
    from mmatch.ego.match.synthetic import dense_pair

    seed, per_view = args
    own, other, gt, _ = dense_pair(seed, per_view)
    other = decode(encode(other))                   # what the Ego receives (quantised)
    return sample_from_frames(own, other, np.column_stack([own.vehicle_box_index[gt[:, 0]],
                                                           other.vehicle_box_index[gt[:, 1]]]), f"synthetic_{seed}")


def synthetic_samples(seed: int, n: int, vehicles: tuple[int, int], jobs: int = 1,
                      progress: Callable[[int, int], None] | None = None) -> list[Sample]:
    """Samples of n synthetic dense frame pairs (ego/match/synthetic.py), vehicles[0]-[1] a view."""
    rng = np.random.default_rng([seed, 77])
    tasks = [(seed * 100_000 + k, int(rng.integers(vehicles[0], vehicles[1] + 1))) for k in range(n)]
    return _run(_synthetic_sample, tasks, jobs, progress)


def _run(fn, tasks, jobs, progress) -> list[Sample]:
    out: list[Sample] = []
    n = len(tasks)
    if jobs <= 1:
        for k, s in enumerate(map(fn, tasks)):
            if s is not None:
                out.append(s)
            if progress:
                progress(k + 1, n)
        return out
    with ProcessPoolExecutor(max_workers=jobs) as pool:
        for k, s in enumerate(pool.map(fn, tasks, chunksize=8)):
            if s is not None:
                out.append(s)
            if progress:
                progress(k + 1, n)
    return out


def simulate_samples(seed: int, n: int, modes: tuple[str, ...] = ("easy", "hard"), jobs: int = 1,
                     progress: Callable[[int, int], None] | None = None, physics: str = "wide") -> list[Sample]:
    """Samples of `n` simulated scenes of data set `seed`, the modes taken in turn (scene k: modes[k % len])."""
    tasks = [(seed, k, modes[k % len(modes)], physics) for k in range(n)]
    return _run(_scene_sample, tasks, jobs, progress)


def save_samples(path: str, samples: list[Sample]) -> None:
    """All samples in one .npz (concatenated arrays with per-sample sizes)."""
    va = np.array([len(s.xa) for s in samples], np.int32)
    vb = np.array([len(s.xb) for s in samples], np.int32)
    np.savez_compressed(
        path, va=va, vb=vb,
        xa=np.concatenate([s.xa for s in samples]), xb=np.concatenate([s.xb for s in samples]),
        ea=np.concatenate([s.ea.reshape(-1, s.ea.shape[-1]) for s in samples]),
        eb=np.concatenate([s.eb.reshape(-1, s.eb.shape[-1]) for s in samples]),
        na=np.concatenate([s.na.ravel() for s in samples]), nb=np.concatenate([s.nb.ravel() for s in samples]),
        ka=np.array([s.ea.shape[1] for s in samples], np.int32), kb=np.array([s.eb.shape[1] for s in samples], np.int32),
        target=np.concatenate([s.target.ravel() for s in samples]),
        names=np.array([s.name for s in samples]))


def load_samples(path: str) -> list[Sample]:
    """The samples `save_samples` wrote."""
    with np.load(path, allow_pickle=False) as z:
        d = {k: z[k] for k in z.files}
    out = []
    oa = ob = oea = oeb = ot = 0
    for k in range(len(d["va"])):
        va, vb, ka, kb = int(d["va"][k]), int(d["vb"][k]), int(d["ka"][k]), int(d["kb"][k])
        out.append(Sample(
            d["xa"][oa:oa + va], d["ea"][oea:oea + va * ka].reshape(va, ka, -1), d["na"][oea:oea + va * ka].reshape(va, ka),
            d["xb"][ob:ob + vb], d["eb"][oeb:oeb + vb * kb].reshape(vb, kb, -1), d["nb"][oeb:oeb + vb * kb].reshape(vb, kb),
            d["target"][ot:ot + va * vb].reshape(va, vb), str(d["names"][k])))
        oa, ob, oea, oeb, ot = oa + va, ob + vb, oea + va * ka, oeb + vb * kb, ot + va * vb
    return out
