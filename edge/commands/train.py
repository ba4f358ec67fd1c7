"""`mmatch train`: simulate scenes, train RM-net, export it to ONNX with its model card.

Needs the `train` extra (`pip install -r requirements-train.txt`: PyTorch, CPU build).
Writes into --out: config.json, history.json, figures/epoch_NNN.png (one per epoch), rmnet.pt
(the torch weights, `RMNet.load_state_dict`) and the exported model with its card (--export,
default OUT/rmnet.onnx; the card is the same name with .md). `mmatch train --out DIR --export
mmatch/models/rmnet.onnx` replaces the model the package ships.
"""

from __future__ import annotations

import argparse

from mmatch.train.request import TrainRequest

HELP = "train RM-net on simulated scenes and export it to ONNX (needs the train extra)"


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("--out", required=True, help="output folder (figures, history, config)")
    p.add_argument("--export", default=TrainRequest.export,
                   help="ONNX file to write (default OUT/rmnet.onnx); card beside it")
    p.add_argument("--scenes", type=int, default=TrainRequest.scenes,
                   help="simulated scene pairs (easy and hard in turn; the shipped model: 14400)")
    p.add_argument("--physics", default=TrainRequest.physics,
                   help="simulator physics: nominal, wide (the family we train on) or a TOML file of ranges")
    p.add_argument("--dense-scenes", type=int, default=TrainRequest.dense_scenes,
                   help="extra hard scene pairs in dense traffic (--dense-vehicles other vehicles)")
    p.add_argument("--dense-vehicles", default=TrainRequest.dense_vehicles,
                   help="LO-HI other vehicles of a dense scene")
    p.add_argument("--synthetic-scenes", type=int, default=TrainRequest.synthetic_scenes,
                   help="extra synthetic dense frame pairs (--synthetic-vehicles a view; the simulator's "
                        "cameras see at most 12-15 vehicles)")
    p.add_argument("--synthetic-vehicles", default=TrainRequest.synthetic_vehicles,
                   help="LO-HI vehicles a view of a synthetic pair")
    p.add_argument("--val-share", type=float, default=TrainRequest.val_share,
                   help="share of the scenes kept for validation")
    p.add_argument("--seed", type=int, default=TrainRequest.seed, help="simulation seed (never the evaluation seeds)")
    p.add_argument("--train-seed", type=int, default=TrainRequest.train_seed,
                   help="seed of initialisation and batch order")
    p.add_argument("--epochs", type=int, default=TrainRequest.epochs, help="length of the cosine schedule")
    p.add_argument("--patience", type=int, default=TrainRequest.patience,
                   help="early stopping: epochs without a better validation loss")
    p.add_argument("--min-epochs", type=int, default=TrainRequest.min_epochs,
                   help="no early stop before this many epochs (early in the schedule the validation loss is "
                        "noisy: a pause of 8 epochs at epoch 29 stopped one run 11 epochs short)")
    p.add_argument("--steps", type=int, default=TrainRequest.steps, help="message-passing steps")
    p.add_argument("--jobs", type=int, default=TrainRequest.jobs, help="simulation worker processes")
    p.add_argument("--threads", type=int, default=TrainRequest.threads,
                   help="torch threads: 2 on an otherwise idle 2-core machine (an epoch 13-20 s against 20-23), "
                        "1 beside other jobs (two threads competing for busy cores crawl)")
    p.add_argument("--appearance-augment", type=float, default=TrainRequest.appearance_augment,
                   help="probability of each appearance rewrite of a training graph: descriptors mixed with "
                        "random histograms, one view's hues turned (mmatch/train/augment.py)")
    p.add_argument("--samples", default=TrainRequest.samples,
                   help="reuse (or write) the simulated samples in this .npz")


def run(args: argparse.Namespace) -> int:
    req = TrainRequest.from_args(args)
    try:
        from mmatch.train.run import train
    except ModuleNotFoundError as exc:
        from mmatch.errors import ConfigError
        raise ConfigError(f"mmatch train needs the train extra ({exc.name} is missing): "
                          "pip install -r requirements-train.txt") from exc
    card = train(req)
    v = card["validation"]
    print(f"exported {card['model']} ({card['bytes']} bytes, {card['parameters']} parameters) in "
          f"{card['training']['total_seconds']:.0f} s; validation P {v['precision']:.3f} R {v['recall']:.3f} "
          f"F1 {v['f1']:.3f}; torch vs ONNX Runtime max |diff| {card['agreement_max_abs']:.1e}")
    return 0
