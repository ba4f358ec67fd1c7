"""Appearance augmentation of RM-net's training graphs: descriptors that say less, cameras that disagree.

Our simulator draws each camera's colour response and the pixels behind a descriptor from the
physics family, but other cameras and detectors give descriptors that say less about a vehicle
(blur, occlusion, another detector's boxes) or render colours differently. A network trained
on one simulator's descriptors alone learns to trust them: on wide hard seed 1 with half of
each histogram replaced by a random one (`mmatch transfer`, "descriptor-noise") the `rmnet`
matcher's pair F1 fell 0.918 -> 0.766, the consensus search's without the network 0.904 -> 0.850.

Each training graph of a batch is, with probability `p` each, (a) given descriptors whose H, S
and V histograms are mixed with a random one (flat Dirichlet) at a share drawn up to `max_mix`,
both views, and (b) given one view's hue histogram turned by up to `max_hue_bins` bins either
way (a fraction spreads each bin over two). The node features hold each descriptor as its
Hellinger embedding (graph.py columns 0-31: square roots, unit length per group), so the
histograms are their squares; the embedding and the local edges' descriptor distance (edge
column 9) are recomputed from the new histograms. Nothing else of a graph depends on appearance.
The whole batch is rewritten at once, on the padded arrays of `data.collate_arrays`.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from mmatch.ego.match.graph import hellinger_embedding
from mmatch.types import DESCRIPTOR_GROUPS

HUE = DESCRIPTOR_GROUPS[0]
DESC_DIM = DESCRIPTOR_GROUPS[-1][1]
EDGE_DESC = 9                   # graph.py: the local edge's descriptor distance


@dataclass(frozen=True)
class AppearanceAugment:
    p: float = 0.0              # probability of each of the two rewrites (0: none)
    max_mix: float = 0.6        # random share of each histogram, drawn from U(0, max_mix)
    max_hue_bins: float = 1.5   # one view's hue turn, drawn from U(-max, max) bins


def _turned(h: np.ndarray, bins: np.ndarray) -> np.ndarray:
    """Hue histograms h (B, V, 16) turned by bins (B,) each (fractions spread over two bins)."""
    n = h.shape[-1]
    k = np.floor(bins).astype(int)
    w = (bins - k)[:, None, None]
    idx = (np.arange(n)[None, :] - k[:, None]) % n                     # np.roll by k, per graph
    rolled = np.take_along_axis(h, idx[:, None, :].repeat(h.shape[1], axis=1), axis=2)
    rolled_next = np.roll(rolled, 1, axis=2)
    return (1 - w) * rolled + w * rolled_next


def _rewrite_view(x: np.ndarray, e: np.ndarray, nbr: np.ndarray, node_mask: np.ndarray, edge_mask: np.ndarray,
                  share: np.ndarray, bins: np.ndarray, rng: np.random.Generator) -> None:
    """One view of a padded batch in place: x (B, V, F), e (B, V, K, Fe), nbr (B, V, K), masks
    (B, V) and (B, V, K); share (B,) mixing shares, bins (B,) hue turns (0: none)."""
    h = np.asarray(x[..., :DESC_DIM], np.float64) ** 2
    s = share[:, None, None]
    for lo, hi in DESCRIPTOR_GROUPS:
        g = h[..., lo:hi]
        if share.any():
            draw = rng.standard_exponential(g.shape)
            g = (1 - s) * g + s * draw / draw.sum(axis=-1, keepdims=True)
        if (lo, hi) == HUE and bins.any():
            g = _turned(g, bins)
        h[..., lo:hi] = g
    emb = hellinger_embedding(h.reshape(-1, DESC_DIM)).reshape(h.shape) * node_mask[..., None]
    x[..., :DESC_DIM] = emb
    if e.shape[2]:
        nb = emb[np.arange(len(emb))[:, None, None], nbr]                 # (B, V, K, 32)
        bc = np.einsum("bvd,bvkd->bvk", emb, nb)
        dist = np.sqrt(np.clip(1 - bc / len(DESCRIPTOR_GROUPS), 0, 1))
        e[..., EDGE_DESC] = np.where(edge_mask > 0, dist, e[..., EDGE_DESC])


def augment_batch(arrays: dict[str, np.ndarray], cfg: AppearanceAugment, rng: np.random.Generator) -> None:
    """Rewrite the appearance of a padded batch (`data.collate_arrays`) in place, graph by graph as
    the module docstring says; graphs that draw neither rewrite keep their features bit for bit."""
    if cfg.p <= 0:
        return
    B = len(arrays["xa"])
    mix = rng.random(B) < cfg.p
    hue = rng.random(B) < cfg.p
    share = np.where(mix, rng.uniform(0, cfg.max_mix, B), 0.0)
    bins = np.where(hue, rng.uniform(-cfg.max_hue_bins, cfg.max_hue_bins, B), 0.0)
    own_side = rng.random(B) < 0.5
    for view, turn in (("a", np.where(own_side, bins, 0.0)), ("b", np.where(own_side, 0.0, bins))):
        rows = mix | (turn != 0)
        if not rows.any():
            continue
        sub = {k: arrays[k + view][rows] for k in ("x", "e", "n", "l", "m")}
        _rewrite_view(sub["x"], sub["e"], sub["n"], sub["m"], sub["l"], share[rows], turn[rows], rng)
        arrays["x" + view][rows] = sub["x"]
        arrays["e" + view][rows] = sub["e"]
