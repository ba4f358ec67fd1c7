"""Camera driver: sources (OpenCV, OAK/depthai, replay, sim), ONNX vehicle detector,
monocular depth, calibration and the appearance descriptor.

Produces `mmatch.types.Detections` (boxes float32 (M, 6) u1, v1, u2, v2, score, depth;
features float32 (M, 32); stamp). Heavy libraries (onnxruntime, depthai) are imported only
inside the function or backend that needs them; `import drivers.camera` is cheap.
"""
