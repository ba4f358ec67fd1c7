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


def test_unpadded_graph_computes_what_training_computes_on_a_padded_batch():
    """The exported graph passes no masks (model.RMNet.forward): a frame pair alone must give the
    logits it gets inside a padded training batch beside a larger one."""
    require_torch()
    import torch

    from mmatch.train.data import synthetic_samples
    from mmatch.train.fit import _forward, collate
    from mmatch.train.model import RMNet

    torch.manual_seed(5)
    net = RMNet().eval()
    small, large = synthetic_samples(7, 2, (4, 12))
    if len(small.xa) > len(large.xa):
        small, large = large, small
    assert len(small.xa) < len(large.xa)               # the small one is padded in the batch
    with torch.no_grad():
        batch = _forward(net, collate([small, large]))
        for k, s in enumerate((small, large)):
            alone = net(*(torch.from_numpy(a)[None] for a in (s.xa, s.xb, s.ea, s.eb, s.na, s.nb)))
            va, vb = len(s.xa), len(s.xb)
            for step_batch, step_alone in zip(batch, alone):
                assert torch.allclose(step_batch[k, :va, :vb], step_alone[0], atol=1e-5)
        assert (batch[-1][0, len(small.xa):, :] < -1e3).all()    # the padding's pairs score nothing
