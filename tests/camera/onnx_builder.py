"""A minimal hand-written ONNX writer (protobuf wire format) so tests need no `onnx` package.

Only what tests use: ModelProto -> GraphProto with nodes, initializers (TensorProto with
raw_data) and typed inputs/outputs. Field numbers follow onnx/onnx.proto (IR version 8).
"""

from __future__ import annotations

import numpy as np

# TensorProto.DataType
FLOAT, UINT8, INT8, INT32, INT64, FLOAT16 = 1, 2, 3, 6, 7, 10
_NP_TO_ONNX = {
    np.dtype(np.float32): FLOAT,
    np.dtype(np.uint8): UINT8,
    np.dtype(np.int8): INT8,
    np.dtype(np.int32): INT32,
    np.dtype(np.int64): INT64,
    np.dtype(np.float16): FLOAT16,
}


def _varint(n: int) -> bytes:
    n &= (1 << 64) - 1
    out = bytearray()
    while True:
        b = n & 0x7F
        n >>= 7
        if n:
            out.append(b | 0x80)
        else:
            out.append(b)
            return bytes(out)


def _key(field: int, wire: int) -> bytes:
    return _varint((field << 3) | wire)


def _int(field: int, value: int) -> bytes:
    return _key(field, 0) + _varint(int(value))


def _bytes(field: int, value: bytes | str) -> bytes:
    if isinstance(value, str):
        value = value.encode()
    return _key(field, 2) + _varint(len(value)) + value


def tensor(name: str, array: np.ndarray) -> bytes:
    """TensorProto: dims (1), data_type (2), name (8), raw_data (9, little-endian)."""
    a = np.ascontiguousarray(array)
    msg = b"".join(_int(1, d) for d in a.shape)
    msg += (
        _int(2, _NP_TO_ONNX[a.dtype])
        + _bytes(8, name)
        + _bytes(9, a.astype(a.dtype.newbyteorder("<")).tobytes())
    )
    return msg


def value_info(name: str, elem_type: int, shape: tuple) -> bytes:
    """ValueInfoProto name (1), type (2) = TypeProto.tensor_type (1) {elem_type (1), shape (2)}.

    A dimension is an int (dim_value, 1) or a str (dim_param, 2)."""
    dims = b""
    for d in shape:
        dim = _bytes(2, d) if isinstance(d, str) else _int(1, d)
        dims += _bytes(1, dim)
    tensor_type = _int(1, elem_type) + _bytes(2, dims)
    return _bytes(1, name) + _bytes(2, _bytes(1, tensor_type))


def attr_tensor(name: str, t: bytes) -> bytes:
    """AttributeProto name (1), t (5), type (20) = TENSOR (4)."""
    return _bytes(1, name) + _bytes(5, t) + _int(20, 4)


def attr_int(name: str, value: int) -> bytes:
    """AttributeProto name (1), i (3), type (20) = INT (2)."""
    return _bytes(1, name) + _int(3, value) + _int(20, 2)


def node(
    op_type: str, inputs: list[str], outputs: list[str], name: str = "", attrs: list[bytes] = ()
) -> bytes:
    """NodeProto input (1), output (2), name (3), op_type (4), attribute (5)."""
    msg = b"".join(_bytes(1, i) for i in inputs) + b"".join(_bytes(2, o) for o in outputs)
    msg += _bytes(3, name or f"{op_type}_{outputs[0]}") + _bytes(4, op_type)
    return msg + b"".join(_bytes(5, a) for a in attrs)


def model(
    nodes: list[bytes],
    inputs: list[bytes],
    outputs: list[bytes],
    initializers: list[bytes] = (),
    opset: int = 17,
) -> bytes:
    """ModelProto ir_version (1), producer_name (2), graph (7), opset_import (8)."""
    graph = b"".join(_bytes(1, n) for n in nodes) + _bytes(2, "test")
    graph += b"".join(_bytes(5, t) for t in initializers)
    graph += b"".join(_bytes(11, i) for i in inputs) + b"".join(_bytes(12, o) for o in outputs)
    opset_msg = _bytes(1, "") + _int(2, opset)
    return _int(1, 8) + _bytes(2, "mmatch-tests") + _bytes(7, graph) + _bytes(8, opset_msg)


def constant_model(
    outputs: dict[str, np.ndarray],
    input_shape: tuple = (1, 3, 64, 64),
    input_name: str = "images",
    input_type: int = FLOAT,
) -> bytes:
    """A "detector" whose outputs are fixed tensors; the image input is accepted and ignored.

    Each output is `Add(constant, 0 * ReduceMax(image))`-free: a plain Constant node, so the
    raw network output the decoder sees is exactly the given array.
    """
    nodes, outs = [], []
    for name, arr in outputs.items():
        arr = np.asarray(arr, np.float32)
        nodes.append(
            node("Constant", [], [name], attrs=[attr_tensor("value", tensor(name + "_c", arr))])
        )
        outs.append(value_info(name, FLOAT, arr.shape))
    return model(nodes, [value_info(input_name, input_type, input_shape)], outs)


def int8_constant_model(
    outputs: dict[str, np.ndarray],
    input_shape: tuple = (1, 3, 64, 64),
    input_name: str = "images",
    axis: int = -1,
) -> tuple[bytes, dict[str, np.ndarray]]:
    """Like `constant_model` but each output is DequantizeLinear(int8 weights, scale, 0) with one
    scale per slice along `axis` (per-channel, as quantizers do): an INT8-quantized graph.
    Returns the model and the exact float outputs it produces."""
    nodes, outs, inits, exact = [], [], [], {}
    for name, arr in outputs.items():
        arr = np.asarray(arr, np.float32)
        ax = axis % arr.ndim
        other = tuple(i for i in range(arr.ndim) if i != ax)
        scale = (np.maximum(np.abs(arr).max(axis=other), 1e-6) / 127.0).astype(np.float32)
        shape = [1] * arr.ndim
        shape[ax] = -1
        q = np.clip(np.round(arr / scale.reshape(shape)), -127, 127).astype(np.int8)
        inits += [
            tensor(name + "_q", q),
            tensor(name + "_s", scale),
            tensor(name + "_z", np.zeros(scale.shape, np.int8)),
        ]
        nodes.append(
            node(
                "DequantizeLinear",
                [name + "_q", name + "_s", name + "_z"],
                [name],
                attrs=[attr_int("axis", ax)],
            )
        )
        outs.append(value_info(name, FLOAT, arr.shape))
        exact[name] = q.astype(np.float32) * scale.reshape(shape)
    return model(nodes, [value_info(input_name, FLOAT, input_shape)], outs, inits), exact


def identity_model(shape: tuple, input_name: str = "raw", output_name: str = "out") -> bytes:
    """Identity from input to output: feeding it the raw network output gives it back."""
    return model(
        [node("Identity", [input_name], [output_name])],
        [value_info(input_name, FLOAT, shape)],
        [value_info(output_name, FLOAT, shape)],
    )


def matmul_model(weight: np.ndarray, input_name: str = "x", output_name: str = "y") -> bytes:
    """y = x @ W with W an initializer (a model quantize_dynamic can quantize)."""
    w = np.asarray(weight, np.float32)
    return model(
        [node("MatMul", [input_name, "W"], [output_name])],
        [value_info(input_name, FLOAT, ("n", w.shape[0]))],
        [value_info(output_name, FLOAT, ("n", w.shape[1]))],
        [tensor("W", w)],
    )


def attr_ints(name: str, values: list[int]) -> bytes:
    """AttributeProto name (1), ints (8, repeated), type (20) = INTS (7)."""
    return _bytes(1, name) + b"".join(_int(8, v) for v in values) + _int(20, 7)


def conv_detector_model(
    weight: np.ndarray, bias: np.ndarray, size: int = 64, stride: int = 8
) -> bytes:
    """A tiny real "detector": images (1, 3, size, size) -> Conv(k = stride = `stride`) ->
    Reshape to (1, C, (size / stride)^2), i.e. a YOLOv8-style (1, 4 + nc, N) output computed
    from the pixels (something a static quantizer can calibrate)."""
    c = weight.shape[0]
    n = (size // stride) ** 2
    nodes = [
        node(
            "Conv",
            ["images", "W", "B"],
            ["feat"],
            attrs=[
                attr_ints("kernel_shape", [stride, stride]),
                attr_ints("strides", [stride, stride]),
            ],
        ),
        node("Reshape", ["feat", "shape"], ["output0"]),
    ]
    inits = [
        tensor("W", np.asarray(weight, np.float32)),
        tensor("B", np.asarray(bias, np.float32)),
        tensor("shape", np.array([1, c, n], np.int64)),
    ]
    return model(
        nodes,
        [value_info("images", FLOAT, (1, 3, size, size))],
        [value_info("output0", FLOAT, (1, c, n))],
        inits,
    )
