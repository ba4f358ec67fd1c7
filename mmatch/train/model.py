"""RM-net in PyTorch: the space-across message-passing network over the cross-view graph.

Shapes (batched, padded): own nodes x_a (B, Va, F); local edges of the own view as each
vehicle's K nearest neighbours, e_a (B, Va, Ka, Fe) with neighbour indices n_a (B, Va, Ka)
and mask l_a (B, Va, Ka); the same for the other view (b); vehicle masks m_a (B, Va),
m_b (B, Vb) (1 = a real vehicle). Cross edges are every own x other pair, (B, Va, Vb, 16),
zero at the start. Hidden sizes follow the paper: 32-d nodes, 16-d edges.

Each message-passing step
  1. updates each view's local edges from the edge and its two end nodes (shared weights),
  2. updates the cross edges from the edge, its two end nodes and their product,
  3. updates every node from both kinds: the mean message over its local edges and the
     mean and max message over its cross edges (skipped after the last step: only the
     cross edges are read then);
and the edge classifier turns the cross edges into a logit per pair after every step (the
loss sums the steps). Linear layers on concatenated [edge, node i, node j] are written as
sums of per-part projections (the same function, less work), neighbours are gathered with
an index (Gather in ONNX) and aggregations are masked sums over a fixed axis: no scatter,
so the ONNX export is exact.
"""

from __future__ import annotations

import torch
from torch import nn

from mmatch.ego.match.graph import EDGE_DIM, NODE_DIM

HIDDEN_NODE = 32
HIDDEN_EDGE = 16
MESSAGE = 16
NEG = -1e4


def _mlp(i: int, h: int, o: int) -> nn.Sequential:
    return nn.Sequential(nn.Linear(i, h), nn.ReLU(), nn.Linear(h, o))


def gather_nodes(h: torch.Tensor, nbr: torch.Tensor) -> torch.Tensor:
    """(B, V, D) node rows at neighbour indices (B, V, K) -> (B, V, K, D)."""
    B, V, D = h.shape
    K = nbr.shape[2]
    offset = (torch.arange(B, device=h.device) * V).view(B, 1, 1)
    flat = (nbr + offset).reshape(-1)
    return h.reshape(B * V, D).index_select(0, flat).reshape(B, V, K, D)


class Step(nn.Module):
    """One space-across message-passing step.

    Per-node projections are one Linear split in parts (fewer, larger operations):
    local edge end nodes (i, j), local message (j), cross edge end node, cross edge product
    factor, cross message; the two views share every weight except the cross end-node ones.
    """

    def __init__(self, H: int = HIDDEN_NODE, E: int = HIDDEN_EDGE, M: int = MESSAGE, last: bool = False) -> None:
        super().__init__()
        self.last = last
        self.E, self.M = E, M
        # local edges: e' = e + Lo(relu(Le e + Li h_i + Lj h_j)); message relu(Me e + Mh h_j)
        # cross edges: c' = c + Co(relu(Ce c + Pa h_i + Pb h_j + (Qa h_i) * (Qb h_j))); message relu(Xe c + Xh h)
        parts = 2 * E + (0 if last else M) + 2 * E + (0 if last else M)
        self.proj_a = nn.Linear(H, parts, bias=False)
        self.proj_b = nn.Linear(H, parts, bias=False)
        self.le, self.lo = nn.Linear(E, E), nn.Linear(E, E)
        self.ce, self.co = nn.Linear(E, E), nn.Linear(E, E)
        if not last:
            self.me = nn.Linear(E, M)
            self.xe = nn.Linear(E, M)
            self.node = _mlp(H + 3 * M, H, H)

    def _split(self, p: torch.Tensor) -> list[torch.Tensor]:
        E, M = self.E, self.M
        sizes = [E, E, E, E] if self.last else [E, E, M, E, E, M]
        return list(torch.split(p, sizes, dim=-1))

    def _local(self, e, li, lj, mh, nbr, lm):
        z = torch.relu(self.le(e) + li.unsqueeze(2) + gather_nodes(lj, nbr))
        e = e + self.lo(z) * lm.unsqueeze(-1)
        if self.last:
            return e, None
        msg = torch.relu(self.me(e) + gather_nodes(mh, nbr)) * lm.unsqueeze(-1)
        return e, msg.sum(2) / lm.sum(2).clamp(min=1.0).unsqueeze(-1)

    def forward(self, ha, hb, ea, eb, c, na, nb, la, lb, mab):
        pa, pb = self._split(self.proj_a(ha)), self._split(self.proj_b(hb))
        if self.last:
            (lia, lja, pea, qa), (lib, ljb, peb, qb) = pa, pb
            mha = mhb = xha = xhb = None
        else:
            (lia, lja, mha, pea, qa, xha), (lib, ljb, mhb, peb, qb, xhb) = pa, pb
        ea, agg_a = self._local(ea, lia, lja, mha, na, la)
        eb, agg_b = self._local(eb, lib, ljb, mhb, nb, lb)
        z = torch.relu(self.ce(c) + pea.unsqueeze(2) + peb.unsqueeze(1) + qa.unsqueeze(2) * qb.unsqueeze(1))
        m = mab.unsqueeze(-1)
        c = c + self.co(z) * m
        if self.last:
            return ha, hb, ea, eb, c
        xe = self.xe(c)
        msg_a = torch.relu(xe + xhb.unsqueeze(1)) * m          # to own node i from pair (i, j)
        msg_b = torch.relu(xe + xha.unsqueeze(2)) * m          # to other node j
        ca_mean = msg_a.sum(2) / mab.sum(2).clamp(min=1.0).unsqueeze(-1)
        cb_mean = msg_b.sum(1) / mab.sum(1).clamp(min=1.0).unsqueeze(-1)
        ha = ha + self.node(torch.cat([ha, agg_a, ca_mean, msg_a.amax(2)], -1))   # masked messages are 0 <= real ones
        hb = hb + self.node(torch.cat([hb, agg_b, cb_mean, msg_b.amax(1)], -1))
        return ha, hb, ea, eb, c


class RMNet(nn.Module):
    """Node/edge encoders, `steps` message-passing steps, and the cross-edge classifier."""

    def __init__(self, steps: int = 3, node_dim: int = NODE_DIM, edge_dim: int = EDGE_DIM) -> None:
        super().__init__()
        self.steps = steps
        self.node_enc = _mlp(node_dim, HIDDEN_NODE, HIDDEN_NODE)
        self.edge_enc = _mlp(edge_dim, HIDDEN_EDGE, HIDDEN_EDGE)
        self.layers = nn.ModuleList([Step(last=k == steps - 1) for k in range(steps)])
        self.classify = _mlp(HIDDEN_EDGE, HIDDEN_EDGE, 1)

    def forward(self, xa, xb, ea, eb, na, nb, la, lb, ma, mb, all_steps: bool = True) -> list[torch.Tensor]:
        """Logits (B, Va, Vb) after each step (or the last only); pairs with a padded vehicle get NEG."""
        mab = ma.unsqueeze(2) * mb.unsqueeze(1)
        ha = self.node_enc(xa) * ma.unsqueeze(-1)
        hb = self.node_enc(xb) * mb.unsqueeze(-1)
        ea = self.edge_enc(ea) * la.unsqueeze(-1)
        eb = self.edge_enc(eb) * lb.unsqueeze(-1)
        c = torch.zeros(xa.shape[0], xa.shape[1], xb.shape[1], HIDDEN_EDGE, dtype=xa.dtype, device=xa.device)
        out = []
        for k, layer in enumerate(self.layers):
            ha, hb, ea, eb, c = layer(ha, hb, ea, eb, c, na, nb, la, lb, mab)
            if all_steps or k == self.steps - 1:
                logit = self.classify(c).squeeze(-1)
                out.append(torch.where(mab > 0, logit, torch.full_like(logit, NEG)))
        return out


class RMNetExport(nn.Module):
    """One frame pair, no padding: what the ONNX file computes.

    Inputs x_own (Va, F), x_other (Vb, F) float32; e_own (Va, Ka, Fe), e_other (Vb, Kb, Fe)
    float32; n_own (Va, Ka), n_other (Vb, Kb) int64 neighbour indices. Output prob (Va, Vb):
    the last step's pair probabilities.
    """

    def __init__(self, net: RMNet) -> None:
        super().__init__()
        self.net = net

    def forward(self, x_own, x_other, e_own, e_other, n_own, n_other):
        xa, xb = x_own.unsqueeze(0), x_other.unsqueeze(0)
        ea, eb = e_own.unsqueeze(0), e_other.unsqueeze(0)
        ma, mb = torch.ones_like(xa[..., 0]), torch.ones_like(xb[..., 0])
        la, lb = torch.ones_like(ea[..., 0]), torch.ones_like(eb[..., 0])
        logit = self.net(xa, xb, ea, eb, n_own.unsqueeze(0), n_other.unsqueeze(0), la, lb, ma, mb,
                         all_steps=False)[-1]
        return torch.sigmoid(logit[0])


def weighted_bce(logits: list[torch.Tensor], target: torch.Tensor, mask: torch.Tensor) -> torch.Tensor:
    """Weighted BCE summed over the steps, omega = #negative / #positive of the batch's real pairs.

    logits: per step (B, Va, Vb); target (B, Va, Vb) 0/1; mask (B, Va, Vb) 1 for real pairs.
    """
    pos = (target * mask).sum()
    neg = ((1 - target) * mask).sum()
    omega = (neg / pos.clamp(min=1.0)).clamp(min=1.0)
    w = mask * (1 + (omega - 1) * target)
    norm = w.sum().clamp(min=1.0)
    total = logits[0].new_zeros(())
    for lg in logits:
        total = total + (nn.functional.binary_cross_entropy_with_logits(lg, target, reduction="none") * w).sum() / norm
    return total
