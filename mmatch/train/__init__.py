"""Training of RM-net (PyTorch; only with the `train` extra). The runtime never imports this package.

model: the network; data: scenes -> graphs with labels; fit: the training loop;
export: ONNX export and the torch/ONNX Runtime agreement check.
"""
