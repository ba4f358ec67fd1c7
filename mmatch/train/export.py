"""Export RM-net to ONNX (dynamo exporter, dynamic vehicle counts) and check it against torch.

The file holds the weights inline (external_data=False), has inputs x_own (Va, NODE_DIM),
x_other (Vb, NODE_DIM), e_own (Va, Ka, EDGE_DIM), e_other (Vb, Kb, EDGE_DIM), n_own (Va, Ka),
n_other (Vb, Kb) (int64 neighbour indices) and output prob (Va, Vb), for any Va, Vb >= 2. The aggregations are masked sums (no scatter), and
`agreement` compares the two runtimes on random graphs of many sizes because exporters
have miscompiled graph networks before (LIBRARIES.md section 5).
"""

from __future__ import annotations

import logging
import warnings
from pathlib import Path

import numpy as np
import torch

from mmatch.ego.match.graph import EDGE_DIM, NODE_DIM, neighbour_count
from mmatch.ego.match.rmnet_runtime import INPUT_NAMES, OUTPUT_NAME
from mmatch.train.model import RMNet, RMNetExport

log = logging.getLogger(__name__)
OPSET = 18
MAX_VEHICLES = 4096


def example_inputs(va: int = 5, vb: int = 7, seed: int = 0) -> tuple[torch.Tensor, ...]:
    """Random inputs of one frame pair (Va own, Vb other vehicles), shaped as graph.py builds them."""
    g = torch.Generator().manual_seed(seed)
    ka, kb = neighbour_count(va), neighbour_count(vb)
    return (torch.randn(va, NODE_DIM, generator=g), torch.randn(vb, NODE_DIM, generator=g),
            torch.randn(va, ka, EDGE_DIM, generator=g), torch.randn(vb, kb, EDGE_DIM, generator=g),
            torch.randint(0, va, (va, ka), generator=g), torch.randint(0, vb, (vb, kb), generator=g))


def export_onnx(net: RMNet, path: str | Path) -> Path:
    """Write `net` as a single-file ONNX model with dynamic vehicle counts; returns the path."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    model = RMNetExport(net).eval()
    va = torch.export.Dim("num_own", min=2, max=MAX_VEHICLES)
    vb = torch.export.Dim("num_other", min=2, max=MAX_VEHICLES)
    ka = torch.export.Dim("k_own", min=2, max=MAX_VEHICLES)
    kb = torch.export.Dim("k_other", min=2, max=MAX_VEHICLES)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        logging.getLogger("torch").setLevel(logging.ERROR)
        torch.onnx.export(
            model, example_inputs(), str(path), dynamo=True, external_data=False, opset_version=OPSET,
            input_names=list(INPUT_NAMES), output_names=[OUTPUT_NAME],
            dynamic_shapes={"x_own": {0: va}, "x_other": {0: vb}, "e_own": {0: va, 1: ka},
                            "e_other": {0: vb, 1: kb}, "n_own": {0: va, 1: ka}, "n_other": {0: vb, 1: kb}},
            verbose=False)
    return path


def agreement(net: RMNet, path: str | Path, sizes: list[tuple[int, int]], seed: int = 0) -> float:
    """Largest |torch - ONNX Runtime| probability over random graphs of the given (Va, Vb) sizes."""
    from mmatch.ego.match.rmnet_runtime import RMNetSession

    sess = RMNetSession(path)
    model = RMNetExport(net).eval()
    worst = 0.0
    for k, (va, vb) in enumerate(sizes):
        inputs = example_inputs(va, vb, seed + k)
        with torch.no_grad():
            ref = model(*inputs).numpy()
        got = sess.run(*(t.numpy() for t in inputs))
        worst = max(worst, float(np.abs(ref - got).max()))
    return worst
