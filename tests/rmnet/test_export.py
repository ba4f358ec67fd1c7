"""torch and ONNX Runtime agree on the exported RM-net (random graphs of many sizes)."""

from __future__ import annotations

import pytest

from .conftest import require_torch


@pytest.fixture(scope="module")
def exported(tmp_path_factory):
    require_torch()
    import torch

    from mmatch.train.export import export_onnx
    from mmatch.train.model import RMNet

    torch.manual_seed(3)
    net = RMNet().eval()
    for p in net.parameters():                   # larger weights than at init: differences show
        p.data.mul_(1.5)
    path = export_onnx(net, tmp_path_factory.mktemp("onnx") / "rmnet.onnx")
    return net, path


def test_torch_and_onnxruntime_agree(exported):
    from mmatch.train.export import agreement

    net, path = exported
    sizes = [(2, 2), (2, 9), (3, 3), (9, 2), (8, 5), (12, 17), (20, 20), (41, 37), (64, 3)]
    worst = agreement(net, path, sizes, seed=11)
    assert worst < 1e-4


def test_single_file_and_small(exported):
    _, path = exported
    assert not path.with_name(path.name + ".data").exists()
    assert path.stat().st_size < 2_000_000
