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
so the ONNX export is exact. The exported graph (one frame pair, nothing padded) passes no
masks: every masking operation drops out of it with the same numbers (301 -> 219 ONNX nodes,
RM-net inference 0.44 -> 0.34 ms at 20 vehicles a side).
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
    if B == 1:          # one frame pair (the ONNX file's case): one Gather
        return nn.functional.embedding(nbr[0], h[0]).unsqueeze(0)
    offset = (torch.arange(B, device=h.device) * V).view(B, 1, 1)
    flat = (nbr + offset).reshape(-1)
    return h.reshape(B * V, D).index_select(0, flat).reshape(B, V, K, D)


def _masked(x: torch.Tensor, mask: torch.Tensor | None) -> torch.Tensor:
    """x (..., D) with the rows of padding (mask 0) zeroed; mask None: nothing is padding."""
    return x if mask is None else x * mask.unsqueeze(-1)


def _mean(x: torch.Tensor, mask: torch.Tensor | None, dim: int) -> torch.Tensor:
    """Mean of x (..., D) over the real rows along dim (padding already zeroed)."""
    if mask is None:
        return x.mean(dim)
    return x.sum(dim) / mask.sum(dim).clamp(min=1.0).unsqueeze(-1)


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
        e = e + _masked(self.lo(z), lm)
        if self.last:
            return e, None
        msg = _masked(torch.relu(self.me(e) + gather_nodes(mh, nbr)), lm)
        return e, _mean(msg, lm, 2)

    def forward(self, ha, hb, ea, eb, c, na, nb, la, lb, mab):
        pa, pb = self._split(self.proj_a(ha)), self._split(self.proj_b(hb))
        if self.last:
            (lia, lja, pea, qa), (lib, ljb, peb, qb) = pa, pb
            mha = mhb = xha = xhb = None
        else:
            (lia, lja, mha, pea, qa, xha), (lib, ljb, mhb, peb, qb, xhb) = pa, pb
        ea, agg_a = self._local(ea, lia, lja, mha, na, la)
        eb, agg_b = self._local(eb, lib, ljb, mhb, nb, lb)
        # c None: the cross edges' zero start (ce(0) is ce's bias: same numbers, fewer operations)
        start = self.ce.bias if c is None else self.ce(c)
        z = torch.relu(start + pea.unsqueeze(2) + peb.unsqueeze(1)
                       + qa.unsqueeze(2) * qb.unsqueeze(1))
        c = _masked(self.co(z), mab) if c is None else c + _masked(self.co(z), mab)
        if self.last:
            return ha, hb, ea, eb, c
        xe = self.xe(c)
        msg_a = _masked(torch.relu(xe + xhb.unsqueeze(1)), mab)     # to own node i from pair (i, j)
        msg_b = _masked(torch.relu(xe + xha.unsqueeze(2)), mab)     # to other node j
        ca_mean, cb_mean = _mean(msg_a, mab, 2), _mean(msg_b, mab, 1)
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

    def forward(self, xa, xb, ea, eb, na, nb, la=None, lb=None, ma=None, mb=None,
                all_steps: bool = True) -> list[torch.Tensor]:
        """Logits (B, Va, Vb) after each step (or the last only); pairs with a padded vehicle get
        NEG.

        Masks None: every vehicle and local edge is real (one unpadded frame pair, what the ONNX
        file computes): the same numbers without the masks' operations."""
        mab = None if ma is None else ma.unsqueeze(2) * mb.unsqueeze(1)
        ha = _masked(self.node_enc(xa), ma)
        hb = _masked(self.node_enc(xb), mb)
        ea = _masked(self.edge_enc(ea), la)
        eb = _masked(self.edge_enc(eb), lb)
        c = None
        out = []
        for k, layer in enumerate(self.layers):
            ha, hb, ea, eb, c = layer(ha, hb, ea, eb, c, na, nb, la, lb, mab)
            if all_steps or k == self.steps - 1:
                logit = self.classify(c).squeeze(-1)
                if mab is not None:
                    logit = torch.where(mab > 0, logit, torch.full_like(logit, NEG))
                out.append(logit)
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
        inputs = (x_own, x_other, e_own, e_other, n_own, n_other)
        logit = self.net(*(t.unsqueeze(0) for t in inputs), all_steps=False)[-1]
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
