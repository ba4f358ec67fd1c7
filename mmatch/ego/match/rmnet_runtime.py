"""Running RM-net's ONNX file with ONNX Runtime (no torch): load, check, infer.

The file is checked once, at start: a missing or unreadable file, or one whose inputs and
output are not RM-net's (names, ranks, feature sizes), raises `ModelError` naming the file
and what was expected. One thread per session (intra and inter op): the matcher runs
beside the rest of the vehicle service on a small computer.
"""

from __future__ import annotations

import logging
from importlib import resources
from pathlib import Path

import numpy as np

from mmatch.ego.match.graph import EDGE_DIM, NODE_DIM
from mmatch.errors import ConfigError

log = logging.getLogger(__name__)

INPUT_NAMES = ("x_own", "x_other", "e_own", "e_other", "n_own", "n_other")
OUTPUT_NAME = "prob"
EXPECTED = {"x_own": ("Va", NODE_DIM), "x_other": ("Vb", NODE_DIM),
            "e_own": ("Va", "Ka", EDGE_DIM), "e_other": ("Vb", "Kb", EDGE_DIM),
            "n_own": ("Va", "Ka"), "n_other": ("Vb", "Kb")}
TYPES = {"x_own": "tensor(float)", "x_other": "tensor(float)", "e_own": "tensor(float)",
         "e_other": "tensor(float)", "n_own": "tensor(int64)", "n_other": "tensor(int64)"}


class ModelError(ConfigError):
    """The RM-net model file is missing, corrupt or not shaped as RM-net."""


def expected_signature() -> str:
    """Human-readable inputs and output an RM-net file must have."""
    ins = ", ".join(f"{n} {TYPES[n][7:-1]} ({', '.join(str(d) for d in EXPECTED[n])})" for n in INPUT_NAMES)
    return f"inputs {ins}; output {OUTPUT_NAME} float32 (Va, Vb)"


def default_model_path() -> Path:
    """The model shipped in the package: mmatch/models/rmnet.onnx."""
    return Path(str(resources.files("mmatch.models").joinpath("rmnet.onnx")))


class RMNetSession:
    """An ONNX Runtime session of an RM-net file, checked at construction."""

    def __init__(self, path: str | Path | None = None) -> None:
        import onnxruntime as ort

        self.path = Path(path) if path is not None else default_model_path()
        if not self.path.is_file():
            raise ModelError(f"RM-net model {self.path}: file not found (expected {expected_signature()})")
        opts = ort.SessionOptions()
        opts.intra_op_num_threads = 1
        opts.inter_op_num_threads = 1
        opts.log_severity_level = 3
        try:
            self.session = ort.InferenceSession(str(self.path), sess_options=opts,
                                                providers=["CPUExecutionProvider"])
        except Exception as exc:           # noqa: BLE001 - ORT raises several unrelated types
            raise ModelError(f"RM-net model {self.path}: not a readable ONNX model ({exc}); "
                             f"expected {expected_signature()}") from exc
        self._check()

    def _check(self) -> None:
        ins = {i.name: i for i in self.session.get_inputs()}
        outs = [o.name for o in self.session.get_outputs()]
        problems = []
        if set(ins) != set(INPUT_NAMES):
            problems.append(f"has inputs {sorted(ins)}")
        else:
            for name in INPUT_NAMES:
                shape, want = ins[name].shape, EXPECTED[name]
                if ins[name].type != TYPES[name]:
                    problems.append(f"input {name} is {ins[name].type}")
                elif len(shape) != len(want) or (isinstance(want[-1], int) and shape[-1] != want[-1]):
                    problems.append(f"input {name} has shape {shape}")
        if outs != [OUTPUT_NAME]:
            problems.append(f"has outputs {outs}")
        if problems:
            raise ModelError(f"RM-net model {self.path}: " + "; ".join(problems)
                             + f" (expected {expected_signature()})")

    def run(self, x_own: np.ndarray, x_other: np.ndarray, e_own: np.ndarray, e_other: np.ndarray,
            n_own: np.ndarray, n_other: np.ndarray) -> np.ndarray:
        """(Va, Vb) float32 pair probabilities; every view needs at least 2 vehicles (graph.py shapes)."""
        feeds = {"x_own": np.ascontiguousarray(x_own, np.float32),
                 "x_other": np.ascontiguousarray(x_other, np.float32),
                 "e_own": np.ascontiguousarray(e_own, np.float32),
                 "e_other": np.ascontiguousarray(e_other, np.float32),
                 "n_own": np.ascontiguousarray(n_own, np.int64),
                 "n_other": np.ascontiguousarray(n_other, np.int64)}
        return self.session.run([OUTPUT_NAME], feeds)[0]

    def run_graph(self, graph) -> np.ndarray:
        """(Va, Vb) pair probabilities of a `graph.CrossGraph`."""
        a, b = graph.own, graph.other
        return self.run(a.nodes, b.nodes, a.edges, b.edges, a.neighbours, b.neighbours)
