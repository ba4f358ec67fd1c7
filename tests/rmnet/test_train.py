"""`mmatch train` end to end on a handful of scenes: simulate, fit, figures, export, card."""

from __future__ import annotations

import json

import numpy as np

from mmatch.edge.cli import main

from .conftest import require_torch


def test_smoke_training_and_export(tmp_path, capsys):
    require_torch()
    out = tmp_path / "train"
    model = tmp_path / "model" / "rmnet.onnx"
    rc = main(["train", "--out", str(out), "--export", str(model), "--scenes", "24", "--epochs", "2",
               "--jobs", "1", "--threads", "1", "--seed", "4242", "--dense-scenes", "2",
               "--dense-vehicles", "30-40", "--synthetic-scenes", "3", "--appearance-augment", "0.5"])
    assert rc == 0
    assert "exported rmnet.onnx" in capsys.readouterr().out
    history = json.loads((out / "history.json").read_text())
    assert [h["epoch"] for h in history] == [0, 1]
    assert all(np.isfinite(h["train_loss"]) and np.isfinite(h["val_loss"]) for h in history)
    assert (out / "figures" / "epoch_000.png").stat().st_size > 1000
    card = (tmp_path / "model" / "rmnet.md").read_text()
    assert "simulation seed 4242" in card and "2 dense-traffic" in card and "3 synthetic dense" in card
    assert "physics wide" in card and "with probability 0.5 each, descriptors mixed" in card
    meta = json.loads(card.split("```json")[1].split("```")[0])
    assert meta["agreement_max_abs"] < 1e-4 and meta["data"]["scenes"] == 24
    assert meta["training"]["appearance_augment"]["p"] == 0.5

    from mmatch.ego.match.graph import build_graph
    from mmatch.ego.match.rmnet_runtime import RMNetSession
    from .conftest import make_frame
    g = build_graph(make_frame([[0, 10], [3, 25], [-4, 40]], seed=1), make_frame([[1, 12], [-2, 30]], seed=2))
    P = RMNetSession(model).run_graph(g)
    assert P.shape == (3, 2) and ((P >= 0) & (P <= 1)).all()


def test_bad_arguments_name_the_key(capsys):
    rc = main(["train", "--out", "/tmp/unused-rmnet", "--val-share", "1.5"])
    assert rc == 2 and "val_share" in capsys.readouterr().err
    rc = main(["train", "--out", "/tmp/unused-rmnet", "--appearance-augment", "-0.1"])
    assert rc == 2 and "appearance_augment" in capsys.readouterr().err
    rc = main(["train", "--out", "/tmp/unused-rmnet", "--min-epochs", "-1"])
    assert rc == 2 and "min_epochs" in capsys.readouterr().err


def test_default_request_is_the_shipped_models_recipe():
    """`mmatch train` with no options trains what mmatch/models/rmnet.md says the shipped model is."""
    from importlib import resources

    from mmatch.train.request import TrainRequest

    card = resources.files("mmatch.models").joinpath("rmnet.md").read_text()
    meta = json.loads(card.split("```json")[1].split("```")[0])
    req, data, training = TrainRequest(out="unused"), meta["data"], meta["training"]
    assert (req.seed, req.scenes, req.physics) == (data["simulation_seed"], data["scenes"], data["physics"])
    assert (req.dense_scenes, req.synthetic_scenes, req.synthetic_vehicles) == \
        (data["dense_scenes"], data["synthetic_scenes"], data["synthetic_vehicles"])
    assert (req.train_seed, req.threads) == (training["seed"], training["threads"])
    assert (req.epochs, req.min_epochs) == (training["epochs"], training["min_epochs"])
    assert req.appearance_augment == training["appearance_augment"]["p"]


def test_the_command_line_defaults_are_the_requests():
    """`mmatch train --out DIR` asks for exactly TrainRequest's defaults (the recipe the card is held to)."""
    import argparse

    from mmatch.edge.commands.train import add_arguments
    from mmatch.train.request import TrainRequest

    p = argparse.ArgumentParser()
    add_arguments(p)
    assert TrainRequest.from_args(p.parse_args(["--out", "x"])) == TrainRequest(out="x")
