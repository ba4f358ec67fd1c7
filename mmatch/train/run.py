"""`mmatch train` end to end: data, fit, figures, export, agreement check, model card."""

from __future__ import annotations

import json
import sys
import textwrap
import time
from dataclasses import asdict
from pathlib import Path

import numpy as np
import torch

from mmatch.errors import ConfigError
from mmatch.train.request import TrainRequest, parse_range
from mmatch.train.augment import AppearanceAugment
from mmatch.train.data import Sample, load_samples, save_samples, simulate_samples, synthetic_samples
from mmatch.train.export import agreement, export_onnx
from mmatch.train.figures import epoch_figure
from mmatch.train.fit import FitConfig, fit

AGREEMENT_SIZES = [(2, 2), (2, 7), (5, 3), (8, 8), (13, 21), (20, 20), (40, 40)]


class Bar:
    """A one-line progress bar on stderr (redrawn at most 5 times a second)."""

    def __init__(self, label: str) -> None:
        self.label, self.t0, self.last = label, time.monotonic(), 0.0

    def __call__(self, done: int, total: int) -> None:
        now = time.monotonic()
        if now - self.last < 0.2 and done < total:
            return
        self.last = now
        frac = done / max(total, 1)
        el = now - self.t0
        eta = el / frac - el if frac > 0 else 0.0
        bar = "#" * int(30 * frac)
        sys.stderr.write(f"\r{self.label} [{bar:<30}] {done}/{total} {el:.0f} s, eta {eta:.0f} s ")
        if done >= total:
            sys.stderr.write("\n")
        sys.stderr.flush()


def _data(req: TrainRequest) -> list[Sample]:
    if req.samples and Path(req.samples).is_file():
        return load_samples(req.samples)
    samples = simulate_samples(req.seed, req.scenes, ("easy", "hard"), req.jobs, Bar("simulate"), req.physics)
    if req.dense_scenes:
        from mmatch.sim.world import traffic_override
        with traffic_override(parse_range(req.dense_vehicles, "dense_vehicles")):
            samples += simulate_samples(req.seed + 1, req.dense_scenes, ("hard",), req.jobs, Bar("simulate dense"),
                                        req.physics)
    if req.synthetic_scenes:
        samples += synthetic_samples(req.seed + 2, req.synthetic_scenes, parse_range(req.synthetic_vehicles,
                                     "synthetic_vehicles"), req.jobs, Bar("synthetic dense"))
    if req.samples:
        save_samples(req.samples, samples)
    return samples


def split(samples: list[Sample], val_share: float, seed: int) -> tuple[list[Sample], list[Sample]]:
    """Training and validation samples (a seeded random split by scene)."""
    order = np.random.default_rng(seed).permutation(len(samples))
    n_val = max(1, int(round(val_share * len(samples))))
    return [samples[i] for i in order[n_val:]], [samples[i] for i in order[:n_val]]


def train(req: TrainRequest) -> dict:
    """Run the whole training; returns the model card's figures."""
    t_start = time.perf_counter()
    out = Path(req.out)
    (out / "figures").mkdir(parents=True, exist_ok=True)
    (out / "config.json").write_text(json.dumps(asdict(req), indent=2))
    reused = bool(req.samples) and Path(req.samples).is_file()
    samples = _data(req)
    t_data = time.perf_counter() - t_start
    if len(samples) < 4:
        raise ConfigError(f"scenes: only {len(samples)} usable frame pairs (2+ vehicles a view); simulate more")
    tr, val = split(samples, req.val_share, req.train_seed)
    cfg = FitConfig(epochs=req.epochs, patience=req.patience, min_epochs=req.min_epochs, steps=req.steps,
                    seed=req.train_seed, threads=req.threads, augment=AppearanceAugment(p=req.appearance_augment))

    def on_epoch(st, history):
        epoch_figure(out / "figures" / f"epoch_{st.epoch:03d}.png", history, cfg.epochs)
        sys.stderr.write(f"\repoch {st.epoch}: train loss {st.train_loss:.4f}, validation loss {st.val_loss:.4f}, "
                         f"P {st.precision:.3f} R {st.recall:.3f} F1 {st.f1:.3f}, top-{cfg.top_k} recall "
                         f"{st.topk_recall:.3f} ({st.seconds:.1f} s)\n")

    net, history = fit(tr, val, cfg, Bar("train"), on_epoch)
    hist = [{k: v for k, v in asdict(h).items() if k not in ("pos_scores", "neg_scores")} for h in history]
    (out / "history.json").write_text(json.dumps(hist, indent=2))
    torch.save(net.state_dict(), out / "rmnet.pt")      # to export again when the graph changes
    export = Path(req.export) if req.export else out / "rmnet.onnx"
    export_onnx(net, export)
    worst = agreement(net, export, AGREEMENT_SIZES)
    if worst > 1e-4:
        raise ConfigError(f"export: torch and ONNX Runtime differ by {worst:.2e} (> 1e-4); {export} is not usable")
    best = min(history, key=lambda h: h.val_loss)
    card = {
        "model": export.name, "bytes": export.stat().st_size,
        "parameters": int(sum(p.numel() for p in net.parameters())), "steps": req.steps,
        "data": {"simulation_seed": req.seed, "scenes": req.scenes, "modes": "easy and hard in turn",
                 "physics": req.physics,
                 "dense_scenes": req.dense_scenes, "dense_vehicles": req.dense_vehicles,
                 "dense_seed": req.seed + 1 if req.dense_scenes else None,
                 "synthetic_scenes": req.synthetic_scenes, "synthetic_vehicles": req.synthetic_vehicles,
                 "synthetic_seed": req.seed + 2 if req.synthetic_scenes else None,
                 "frame_pairs": len(samples), "train": len(tr), "validation": len(val),
                 "cav_side": "the real CAV-side pipeline (mmatch.cav.process) on both views"},
        "training": {"seed": req.train_seed, "epochs": req.epochs, "min_epochs": req.min_epochs,
                     "epochs_run": len(history), "best_epoch": best.epoch,
                     "appearance_augment": asdict(cfg.augment),
                     "torch": torch.__version__, "threads": req.threads,
                     "data_seconds": round(t_data, 1), "samples_reused": reused,
                 "total_seconds": round(time.perf_counter() - t_start, 1)},
        "validation": {"loss": best.val_loss, "precision": best.precision, "recall": best.recall, "f1": best.f1,
                       f"top{cfg.top_k}_recall": best.topk_recall},
        "agreement_max_abs": worst,
    }
    write_card(export.with_suffix(".md"), card)
    return card


def _augment_line(a: dict | None) -> str:
    if not a or not a.get("p"):
        return "no appearance augmentation;"
    return (f"appearance augmentation (mmatch/train/augment.py): with probability {a['p']} each, descriptors mixed "
            f"with random histograms up to {a['max_mix']} and one view's hues turned up to {a['max_hue_bins']} bins;")


def _reexport_line(r: dict | None) -> str:
    if not r:
        return ""
    text = (f"- Re-exported {r['date']} from the same weights with a leaner graph ({r['why']}): "
            f"{r['nodes_before']} -> {r['nodes']} ONNX nodes; the two files' outputs on random "
            f"graphs of 2-40 vehicles a side differ by at most {r['max_abs_vs_before']:.1e}.")
    return textwrap.fill(text, 100, subsequent_indent="  ") + "\n"


def write_card(path: Path, card: dict) -> None:
    """The model card: what the model was trained on, how, and how it scored (Markdown + JSON block)."""
    d, t, v = card["data"], card["training"], card["validation"]
    text = f"""# RM-net model card: {card['model']}

The learned co-visible matcher of MMatch (mmatch/ego/match/rmnet.py; network in
mmatch/train/model.py). Written by `mmatch train`; inputs and shapes in mmatch/ego/match/graph.py.

- Size: {card['parameters']} parameters, {card['bytes']} bytes, {card['steps']} message-passing steps
  (32-d nodes, 16-d edges), ONNX opset 18, one file.
- Data: {d['frame_pairs']} frame pairs with 2+ vehicles a view: simulated scenes ({d['scenes']}, {d['modes']},
  physics {d.get('physics', 'nominal')}, simulation seed {d['simulation_seed']}) plus {d['dense_scenes']} dense-traffic hard scenes ({d['dense_vehicles']} other
  vehicles, seed {d['dense_seed']}), both through {d['cav_side']}, plus {d['synthetic_scenes']} synthetic dense
  frame pairs ({d['synthetic_vehicles']} vehicles a view, mmatch/ego/match/synthetic.py, seed {d['synthetic_seed']});
  each pair also seen from the other vehicle. Split by scene: {d['train']} training, {d['validation']} validation.
- Training: weighted BCE over the steps (omega = #negative / #positive), AdamW, cosine schedule,
  seed {t['seed']}, early stopping on the validation loss (not before epoch {t.get('min_epochs', 0)}): {t['epochs_run']} epochs
  run of {t.get('epochs', t['epochs_run'])}, best {t['best_epoch']};
  {_augment_line(t.get('appearance_augment'))}
  torch {t['torch']}, {t['threads']} thread(s); {t['data_seconds']} s {'loading the saved samples' if t['samples_reused'] else 'simulating'}, {t['total_seconds']} s in all.
- Validation (last step, mutual-best pairs above 0.5, no geometry): precision {v['precision']:.3f},
  recall {v['recall']:.3f}, F1 {v['f1']:.3f}; true partner within a vehicle's top 3: {v['top3_recall']:.3f}.
- torch vs ONNX Runtime on random graphs of 2-40 vehicles a side: max |difference| {card['agreement_max_abs']:.1e}.
{_reexport_line(card.get('reexport'))}
```json
{json.dumps(card, indent=2)}
```
"""
    path.write_text(text)
