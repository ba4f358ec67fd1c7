"""Appearance augmentation of RM-net's training graphs: descriptors that say less, cameras that disagree.

Our simulator draws each camera's colour response and the pixels behind a descriptor from the
physics family, but other cameras and detectors give descriptors that say less about a vehicle
(blur, occlusion, another detector's boxes) or render colours differently. A network trained
on one simulator's descriptors alone learns to trust them: on wide hard seed 1 with half of
each histogram replaced by a random one (`mmatch transfer`, "descriptor-noise") the `rmnet`
matcher's pair F1 fell 0.918 -> 0.766, the consensus search's without the network 0.904 -> 0.850.

Each training graph is, with probability `p` each, (a) given descriptors whose H, S and V
histograms are mixed with a random one (flat Dirichlet) at a share drawn up to `max_mix`, both
views, and (b) given one view's hue histogram turned by up to `max_hue_bins` bins either way
(a fraction spreads each bin over two). The node features hold each descriptor as its
Hellinger embedding (graph.py columns 0-31: square roots, unit length per group), so the
histograms are their squares; the embedding and the local edges' descriptor distance (edge
column 9) are recomputed from the new histograms. Nothing else of a graph depends on appearance.
"""

from __future__ import annotations

from dataclasses import dataclass, replace

import numpy as np

from mmatch.ego.match.graph import DESC_GROUPS, hellinger_embedding
from mmatch.train.data import Sample

HUE = DESC_GROUPS[0]
DESC_DIM = DESC_GROUPS[-1][1]
EDGE_DESC = 9                   # graph.py: the local edge's descriptor distance


@dataclass(frozen=True)
class AppearanceAugment:
    p: float = 0.0              # probability of each of the two rewrites (0: none)
    max_mix: float = 0.6        # random share of each histogram, drawn from U(0, max_mix)
    max_hue_bins: float = 1.5   # one view's hue turn, drawn from U(-max, max) bins


def _histograms(x: np.ndarray) -> np.ndarray:
    return np.asarray(x[:, :DESC_DIM], np.float64) ** 2


def _mixed(h: np.ndarray, share: float, rng: np.random.Generator) -> np.ndarray:
    out = h.copy()
    for lo, hi in DESC_GROUPS:
        out[:, lo:hi] = (1 - share) * h[:, lo:hi] + share * rng.dirichlet(np.ones(hi - lo), len(h))
    return out


def _turned(h: np.ndarray, bins: float) -> np.ndarray:
    k, w = int(np.floor(bins)), bins - np.floor(bins)
    lo, hi = HUE
    out = h.copy()
    out[:, lo:hi] = (1 - w) * np.roll(h[:, lo:hi], k, axis=1) + w * np.roll(h[:, lo:hi], k + 1, axis=1)
    return out


def _view(x: np.ndarray, e: np.ndarray, nbr: np.ndarray, h: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Node and edge features of one view with histograms h (V, 32) in place of its own."""
    emb = hellinger_embedding(h)
    x = x.copy()
    x[:, :DESC_DIM] = emb
    e = e.copy()
    if e.shape[1]:
        bc = np.einsum("vd,vkd->vk", emb, emb[nbr])
        e[..., EDGE_DESC] = np.sqrt(np.clip(1 - bc / len(DESC_GROUPS), 0, 1))
    return x.astype(np.float32), e.astype(np.float32)


def augment(s: Sample, cfg: AppearanceAugment, rng: np.random.Generator) -> Sample:
    """The sample with its appearance rewritten as the module docstring says (itself when neither applies)."""
    mix = cfg.p > 0 and rng.random() < cfg.p
    hue = cfg.p > 0 and rng.random() < cfg.p
    if not (mix or hue):
        return s
    ha, hb = _histograms(s.xa), _histograms(s.xb)
    if mix:
        share = rng.uniform(0, cfg.max_mix)
        ha, hb = _mixed(ha, share, rng), _mixed(hb, share, rng)
    if hue:
        bins = rng.uniform(-cfg.max_hue_bins, cfg.max_hue_bins)
        if rng.random() < 0.5:
            ha = _turned(ha, bins)
        else:
            hb = _turned(hb, bins)
    xa, ea = _view(s.xa, s.ea, s.na, ha)
    xb, eb = _view(s.xb, s.eb, s.nb, hb)
    return replace(s, xa=xa, ea=ea, xb=xb, eb=eb)
