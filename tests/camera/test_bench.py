import numpy as np

from mmatch.drivers.camera.bench import run


def test_quick_bench_returns_flat_numbers():
    out = run(quick=True)
    assert out["boxes_found_v8"] == 20.0
    assert all(isinstance(v, float) and np.isfinite(v) for v in out.values())
    for key in (
        "decode_v8_ms",
        "decode_v5_ms",
        "decode_centernet_ms",
        "descriptor_20_ms",
        "frame_v8_ms",
        "descriptor_plus_decode_v8_ms",
    ):
        assert 0.0 < out[key] < 1000.0  # sanity only; speed is judged by `mmatch bench`
