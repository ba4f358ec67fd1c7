"""Loading RM-net's ONNX file: bad files fail at start naming the file and the expected inputs."""

from __future__ import annotations

import numpy as np
import onnx
import pytest
from onnx import TensorProto, helper

from mmatch.ego.match.rmnet_runtime import ModelError, RMNetSession, default_model_path


def test_missing_file_names_it_and_the_inputs(tmp_path):
    path = tmp_path / "nope.onnx"
    with pytest.raises(ModelError) as exc:
        RMNetSession(path)
    assert str(path) in str(exc.value) and "x_own" in str(exc.value) and "n_other" in str(exc.value)


def test_corrupt_file(tmp_path):
    path = tmp_path / "rmnet.onnx"
    path.write_bytes(b"\x08\x07garbage" + bytes(range(256)))
    with pytest.raises(ModelError) as exc:
        RMNetSession(path)
    assert str(path) in str(exc.value) and "expected inputs x_own" in str(exc.value)


def _identity_model(path, feature_dim: int) -> None:
    x = helper.make_tensor_value_info("x_own", TensorProto.FLOAT, ["Va", feature_dim])
    y = helper.make_tensor_value_info("prob", TensorProto.FLOAT, ["Va", feature_dim])
    graph = helper.make_graph([helper.make_node("Identity", ["x_own"], ["prob"])], "g", [x], [y])
    model = helper.make_model(graph, opset_imports=[helper.make_opsetid("", 18)])
    model.ir_version = 8
    onnx.save(model, str(path))


def test_wrongly_shaped_model(tmp_path):
    path = tmp_path / "other.onnx"
    _identity_model(path, 10)
    with pytest.raises(ModelError) as exc:
        RMNetSession(path)
    msg = str(exc.value)
    assert str(path) in msg and "has inputs ['x_own']" in msg and "e_own float (Va, Ka, 10)" in msg


def test_shipped_model_scores_pairs():
    sess = RMNetSession()
    assert sess.path == default_model_path()
    from mmatch.ego.match.graph import build_graph
    from .conftest import make_frame
    g = build_graph(make_frame([[0, 10], [3, 25], [-4, 40]], seed=1), make_frame([[1, 12], [-2, 30]], seed=2))
    p = sess.run_graph(g)
    assert p.shape == (3, 2) and p.dtype == np.float32 and ((p >= 0) & (p <= 1)).all()
