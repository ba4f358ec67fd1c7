"""The RM-net training loop: seeded, validation split, early stopping, per-epoch metrics.

Batches are padded to the largest views of the batch (masks say which rows are real).
Every epoch: weighted BCE over the steps on the training samples (each frame pair also
seen from the other vehicle), then on the validation samples the loss and pair figures of
the last step: precision, recall and F1 of mutual-best pairs above 0.5, and the share of
true pairs whose partner is among a vehicle's top-k (what the matcher's pruning keeps).
"""

from __future__ import annotations

import copy
import logging
import time
from collections.abc import Callable
from dataclasses import asdict, dataclass, field

import numpy as np
import torch

from mmatch.train.augment import AppearanceAugment, augment_batch
from mmatch.train.data import Sample, collate_arrays
from mmatch.train.model import RMNet, weighted_bce

log = logging.getLogger(__name__)


@dataclass(frozen=True)
class FitConfig:
    epochs: int = 60
    batch: int = 64
    lr: float = 3e-3
    weight_decay: float = 1e-5
    patience: int = 8            # epochs without a better validation loss before stopping ...
    min_epochs: int = 0          # ... once this many epochs have run
    steps: int = 3               # message-passing steps
    top_k: int = 3               # partners per vehicle the matcher keeps (for the top-k recall figure)
    seed: int = 0
    threads: int = 1             # torch threads (TrainRequest's default is 2: see edge/commands/train.py)
    augment: AppearanceAugment = AppearanceAugment()   # appearance rewrites of training graphs (augment.py)


@dataclass
class EpochStats:
    epoch: int
    train_loss: float
    val_loss: float
    precision: float
    recall: float
    f1: float
    topk_recall: float
    seconds: float
    pos_scores: list = field(default_factory=list, repr=False)   # validation scores of true pairs
    neg_scores: list = field(default_factory=list, repr=False)   # and of false pairs


def collate(samples: list[Sample]) -> dict[str, torch.Tensor]:
    """Pad a list of samples into batch tensors (see model.RMNet.forward)."""
    return _tensors(collate_arrays(samples))


def _tensors(arrays: dict[str, np.ndarray]) -> dict[str, torch.Tensor]:
    return {k: torch.from_numpy(v) for k, v in arrays.items()}


def _forward(net: RMNet, b: dict[str, torch.Tensor], all_steps: bool = True) -> list[torch.Tensor]:
    return net(b["xa"], b["xb"], b["ea"], b["eb"], b["na"], b["nb"], b["la"], b["lb"], b["ma"], b["mb"],
               all_steps=all_steps)


def pair_figures(prob: np.ndarray, target: np.ndarray, top_k: int) -> tuple[int, int, int, int]:
    """(true positives, predicted, true pairs, true pairs within the top-k of their row and column)."""
    if prob.size == 0:
        return 0, 0, int(target.sum()), 0
    row_best = prob.argmax(axis=1)
    col_best = prob.argmax(axis=0)
    i = np.arange(prob.shape[0])
    mutual = col_best[row_best] == i
    pred = mutual & (prob[i, row_best] > 0.5)
    tp = int(target[i[pred], row_best[pred]].sum())
    rank_row = (-prob).argsort(axis=1).argsort(axis=1)
    rank_col = (-prob).argsort(axis=0).argsort(axis=0)
    kept = (rank_row < top_k) | (rank_col < top_k)
    return tp, int(pred.sum()), int(target.sum()), int((kept & (target > 0)).sum())


def evaluate(net: RMNet, samples: list[Sample], cfg: FitConfig) -> tuple[float, tuple, list, list]:
    """Validation loss and pair figures of the last step; also the scores of true and false pairs."""
    net.eval()
    loss, n = 0.0, 0
    tp = pred = gt = kept = 0
    pos, neg = [], []
    with torch.no_grad():
        for lo in range(0, len(samples), cfg.batch):
            chunk = samples[lo:lo + cfg.batch]
            b = collate(chunk)
            logits = _forward(net, b)
            mask = b["ma"].unsqueeze(2) * b["mb"].unsqueeze(1)
            loss += float(weighted_bce(logits[-1:], b["target"], mask)) * len(chunk)
            n += len(chunk)
            prob = torch.sigmoid(logits[-1]).numpy()
            for k, s in enumerate(chunk):
                p = prob[k, :len(s.xa), :len(s.xb)]
                f = pair_figures(p, s.target, cfg.top_k)
                tp, pred, gt, kept = tp + f[0], pred + f[1], gt + f[2], kept + f[3]
                pos.extend(p[s.target > 0].tolist())
                neg.extend(p[s.target == 0].tolist())
    return loss / max(n, 1), (tp, pred, gt, kept), pos, neg


def _batches(sizes: np.ndarray, batch: int, rng: np.random.Generator) -> list[np.ndarray]:
    """Batches of samples of similar size (padding costs the largest graph's size), in random order.

    Samples are ordered by size with a random jitter (so batches differ between epochs), cut
    into batches, and the batches shuffled.
    """
    order = np.argsort(np.log1p(sizes) + rng.uniform(0, 0.5, len(sizes)), kind="stable")
    out = [order[lo:lo + batch] for lo in range(0, len(order), batch)]
    return [out[i] for i in rng.permutation(len(out))]


def fit(train: list[Sample], val: list[Sample], cfg: FitConfig = FitConfig(),
        progress: Callable[[int, int], None] | None = None,
        on_epoch: Callable[[EpochStats, list[EpochStats]], None] | None = None) -> tuple[RMNet, list[EpochStats]]:
    """Train RM-net; returns the network of the best validation loss and the per-epoch figures."""
    torch.manual_seed(cfg.seed)
    torch.set_num_threads(cfg.threads)
    rng = np.random.default_rng(cfg.seed)
    aug_rng = np.random.default_rng(cfg.seed + 1)
    net = RMNet(steps=cfg.steps)
    opt = torch.optim.AdamW(net.parameters(), lr=cfg.lr, weight_decay=cfg.weight_decay)
    sched = torch.optim.lr_scheduler.CosineAnnealingLR(opt, T_max=cfg.epochs, eta_min=cfg.lr * 0.05)
    history: list[EpochStats] = []
    best, best_state, stale = np.inf, copy.deepcopy(net.state_dict()), 0
    pool = train + [s.swapped() for s in train]
    sizes = np.array([len(s.xa) * len(s.xb) for s in pool], float)
    batches_per_epoch = len(_batches(sizes, cfg.batch, np.random.default_rng(0)))
    for epoch in range(cfg.epochs):
        t0 = time.perf_counter()
        net.train()
        total = 0.0
        for k, idx in enumerate(_batches(sizes, cfg.batch, rng)):
            arrays = collate_arrays([pool[i] for i in idx])
            augment_batch(arrays, cfg.augment, aug_rng)
            b = _tensors(arrays)
            mask = b["ma"].unsqueeze(2) * b["mb"].unsqueeze(1)
            loss = weighted_bce(_forward(net, b), b["target"], mask)
            opt.zero_grad()
            loss.backward()
            torch.nn.utils.clip_grad_norm_(net.parameters(), 5.0)
            opt.step()
            total += float(loss.detach())
            if progress:
                progress(epoch * batches_per_epoch + k + 1, cfg.epochs * batches_per_epoch)
        sched.step()
        vloss, (tp, pred, gt, kept), pos, neg = evaluate(net, val, cfg)
        p = tp / pred if pred else 0.0
        r = tp / gt if gt else 0.0
        st = EpochStats(epoch, total / batches_per_epoch, vloss, p, r, 2 * p * r / (p + r) if p + r else 0.0,
                        kept / gt if gt else 0.0, time.perf_counter() - t0, pos, neg)
        history.append(st)
        log.info("epoch %d: %s", epoch,
                 {k: v for k, v in asdict(st).items() if k not in ("pos_scores", "neg_scores")})
        if on_epoch:
            on_epoch(st, history)
        if vloss < best - 1e-4:
            best, best_state, stale = vloss, copy.deepcopy(net.state_dict()), 0
        else:
            stale += 1
            if stale >= cfg.patience and epoch + 1 >= cfg.min_epochs:
                break
    net.load_state_dict(best_state)
    net.eval()
    return net, history
