"""The per-frame Node: pairing by capture time, several CAVs, link loss and return, bad input."""

from __future__ import annotations

import numpy as np
import pytest
from edge_fakes import FAKE, encode, process_view

from mmatch.edge import config, keys
from mmatch.edge.logschema import SensorFrame, stamp_key
from mmatch.edge.node import Node
from mmatch.edge.sources.base import default_camera
from mmatch.errors import DecodeError


def _cfg(role="ego", cavs=("cav1",), **ego):
    return config.from_dict({"vehicle": {"id": "ego1", "role": role},
                             "ego": {"cavs": list(cavs), "pair_tolerance_s": 0.06, "link_timeout_s": 0.5, **ego}})


def _frame(seq, stamp):
    pts = np.full((4, 5), seq, np.float32)
    return SensorFrame(seq=seq, stamp=stamp, points=pts, boxes=np.zeros((0, 6), np.float32),
                       features=np.zeros((0, 32), np.float32))


def _cav_bytes(sender, seq, stamp):
    sf, _ = process_view(np.full((2, 5), 10 + seq, np.float32), None, None, None, 1.0, stamp, sender=sender, seq=seq)
    return encode(sf)


def _big_frame(sender, vehicles=0, points=0, background=0, stamp=1.0, signer=None):
    from mmatch.shared import SharedFrame

    rng = np.random.default_rng(0)
    V = vehicles
    return encode(SharedFrame(
        sender=sender, seq=1, stamp=stamp, radar_height=1.0,
        vehicle_boxes=np.tile(np.array([[10, 10, 20, 20, 0.9, 10]], np.float32), (V, 1)),
        vehicle_box_index=np.arange(V, dtype=np.int32),
        vehicle_centers=rng.uniform(-50, 50, (V, 2)).astype(np.float32),
        vehicle_features=np.zeros((V, 32), np.float32),
        vehicle_points=rng.uniform(-50, 50, (points, 5)).astype(np.float32),
        vehicle_index=np.zeros(points, np.int32),
        background=rng.uniform(-50, 50, (background, 3)).astype(np.float32)), signer)


def _node(cfg, published=None):
    pub = (lambda k, d: published.append((k, d))) if published is not None else None
    return Node(cfg, FAKE, default_camera(), 0.7, publish=pub)


def test_pairs_with_the_closest_cav_frame_within_tolerance():
    node = _node(_cfg())
    for i, s in enumerate([9.90, 9.95, 10.00, 10.05]):
        node.on_shared("cav1", _cav_bytes("cav1", i, s))
    msg = node.process(_frame(1, 10.02))
    assert msg["status"] == "fused" and not msg["single_vehicle"]
    (c,) = msg["cavs"]
    assert c["seq"] == 2 and c["dt"] == pytest.approx(-0.02)
    assert msg["links"] == {"cav1": "up"} and msg["gap"] is False
    # nothing within tolerance: own perception, flagged single
    msg = node.process(_frame(2, 10.20))
    assert msg["status"] == "single" and msg["single_vehicle"] and msg["cavs"] == []


def test_several_cavs_at_once():
    node = _node(_cfg(cavs=()))
    node.on_shared("cav1", _cav_bytes("cav1", 1, 5.00))
    node.on_shared("cav2", _cav_bytes("cav2", 7, 5.03))
    node.on_shared("cav3", _cav_bytes("cav3", 2, 4.80))  # too old for the tolerance
    msg = node.process(_frame(1, 5.01))
    assert [c["id"] for c in msg["cavs"]] == ["cav1", "cav2"]
    assert msg["status"] == "fused"
    # own 3 objects + 2 from each fused CAV (source 1)
    obj = np.array(msg["objects"])
    assert (obj[:, 2] == 0).sum() == 3 and (obj[:, 2] == 1).sum() == 4


def test_link_loss_is_flagged_and_fusion_resumes_without_restart():
    published = []
    node = _node(_cfg(), published)
    statuses = []
    t = 100.0
    for k in range(60):  # 3 s at 20 Hz; the CAV is silent from 1.0 s to 2.0 s
        stamp = t + 0.05 * k
        if not (1.0 <= 0.05 * k < 2.0):
            node.on_shared("cav1", _cav_bytes("cav1", k, stamp - 0.01))
        msg = node.process(_frame(k, stamp))
        statuses.append((round(0.05 * k, 2), msg["status"], msg["links"]["cav1"]))
    lost = [s for s in statuses if s[2] == "lost"]
    assert lost, "the gap must be flagged"
    # lost only after link_timeout_s of silence, and only until the CAV returns
    assert min(s[0] for s in lost) == pytest.approx(1.0 + 0.5, abs=0.051)
    assert max(s[0] for s in lost) < 2.0
    assert all(s[1] == "single" for s in statuses if 1.0 <= s[0] < 2.0)
    assert all(s[1] == "fused" for s in statuses if s[0] >= 2.0)
    assert node.links["cav1"].gaps == 1
    fused_keys = {k for k, _ in published}
    assert fused_keys == {keys.fused("ego1")}
    assert len(published) == 60


def test_bad_and_foreign_frames_are_dropped_and_counted():
    node = _node(_cfg())
    with pytest.raises(DecodeError):
        node.on_shared("cav1", b"garbage")
    with pytest.raises(DecodeError):
        node.on_shared("cav1", _cav_bytes("cav9", 1, 1.0))  # sender does not match its key
    with pytest.raises(DecodeError, match="too large|over the caps"):
        node.on_shared("cav1", _big_frame("cav1", vehicles=5000))  # refused at decode
    node.on_shared("cav2", _cav_bytes("cav2", 1, 1.0))      # not one of ego.cavs
    node.on_shared("ego1", _cav_bytes("ego1", 1, 1.0))      # our own echo
    assert node.counters.rx == 0
    assert node.counters.rx_rejected == {"malformed": 1, "caps": 1, "sender_mismatch": 1, "foreign": 1}
    assert node.process(_frame(1, 1.0))["status"] == "single"


def test_cav_role_publishes_shared_frames():
    published = []
    node = Node(_cfg(role="cav"), FAKE, default_camera(), 0.7,
                publish=lambda k, d: published.append((k, d)))
    assert node.process(_frame(3, 2.0)) is None
    assert published[0][0] == keys.shared("ego1")
    assert FAKE.decode(published[0][1]).seq == 3   # unsigned (no signer): the frame counter


def test_loop_survives_a_pipeline_failure_on_one_frame():
    from dataclasses import replace

    from mmatch.edge.loop import VehicleLoop
    from mmatch.edge.sources.base import NoCamera
    from mmatch.types import RadarFrame

    calls = []

    def flaky_view(points, *a, **k):
        calls.append(1)
        if len(calls) == 2:
            raise ValueError("odd input")
        return FAKE.process_view(points, *a, **k)

    cfg = config.from_dict({"vehicle": {"id": "cav1", "role": "cav"}, "camera": {"source": "none"}})

    class Radar(NoCamera):
        raw_topic = "/raw/uart"
        lossless = False

    loop = VehicleLoop(cfg, Radar(), NoCamera(), replace(FAKE, process_view=flaky_view))
    for k in range(3):
        loop._step(RadarFrame(points=np.ones((3, 5), np.float32), stamp=float(k)))
    assert len(calls) == 3 and loop.drops["pipeline_error"] == 1 and loop.node.counters.frames == 3


def test_frame_budget_leaves_out_further_cavs_and_a_replay_leaves_out_the_same():
    import time as _time
    from dataclasses import replace

    def slow_fuse(own, other, config=None):
        if other is not None:
            _time.sleep(0.1)
        return FAKE.fuse(own, other)

    cfg = _cfg(cavs=("cav1", "cav2", "cav3"))
    live = Node(cfg, replace(FAKE, fuse=slow_fuse), default_camera(), 0.7, budget_s=0.15)
    again = Node(cfg, FAKE, default_camera(), 0.7)           # a replay: no budget of its own
    for node in (live, again):
        for c in ("cav1", "cav2", "cav3"):
            node.on_shared(c, _cav_bytes(c, 1, 10.0))
    msg = live.process(_frame(1, 10.01))
    assert [c["id"] for c in msg["cavs"]] == ["cav1", "cav2"] and msg["budget_skipped"] == ["cav3"]
    assert live.counters.budget_skipped == 1 and live.summary()["budget_skipped"] == 1
    again.replay_skips = {(1, 10_010_000_000): ["cav3"]}
    rep = again.process(_frame(1, 10.01))
    assert [c["id"] for c in rep["cavs"]] == ["cav1", "cav2"] and rep["budget_skipped"] == ["cav3"]
    # a budget that keeps running out: the CAV fused least recently goes first, so each takes
    # its turn at being left out (and a replay, given the same skips, fuses in the same order)
    skipped, order = [], []
    for k in range(2, 5):
        for node in (live, again):
            for c in ("cav1", "cav2", "cav3"):
                node.on_shared(c, _cav_bytes(c, k, 10.0 + 0.05 * k))
        msg = live.process(_frame(k, 10.01 + 0.05 * k))
        skipped.append(msg["budget_skipped"])
        order.append([c["id"] for c in msg["cavs"]])
        again.replay_skips = {(k, stamp_key(10.01 + 0.05 * k)): msg["budget_skipped"]}
        assert [c["id"] for c in again.process(_frame(k, 10.01 + 0.05 * k))["cavs"]] == order[-1]
    assert skipped == [["cav2"], ["cav1"], ["cav3"]]
    assert order == [["cav3", "cav1"], ["cav2", "cav3"], ["cav1", "cav2"]]


def test_every_cav_mode_caps_links_and_forgets_silent_ones():
    node = _node(_cfg(cavs=(), max_links=2, link_expire_s=5.0))
    node.on_shared("cav1", _cav_bytes("cav1", 1, 100.0))
    node.on_shared("cav2", _cav_bytes("cav2", 1, 100.0))
    with pytest.raises(DecodeError, match="link_cap"):
        node.on_shared("cav3", _cav_bytes("cav3", 1, 100.0))
    assert node.counters.rx_rejected["link_cap"] == 1
    assert set(node.process(_frame(1, 100.01))["links"]) == {"cav1", "cav2"}
    for k in range(2, 8):                                    # cav2 goes silent, cav1 keeps talking
        node.on_shared("cav1", _cav_bytes("cav1", k, 100.0 + k))
        node.process(_frame(k, 100.01 + k))
    assert set(node.links) == {"cav1"} and node.counters.links_expired == 1
    node.on_shared("cav3", _cav_bytes("cav3", 1, 108.0))     # its link was freed
    assert set(node.process(_frame(9, 108.01))["links"]) == {"cav1", "cav3"}


def test_fused_message_carries_confidence_covariance_and_ambiguity_as_json():
    import json as _json
    from dataclasses import replace

    def fuse(own, other, config=None):
        r = FAKE.fuse(own, other)
        r.confidence, r.ambiguity = 0.8, float("nan")
        r.covariance = np.diag([0.04, 0.09, np.nan])
        return r

    published = []
    node = Node(_cfg(), replace(FAKE, fuse=fuse), default_camera(), 0.7,
                publish=lambda k, d: published.append(d))
    node.on_shared("cav1", _cav_bytes("cav1", 1, 10.0))
    node.process(_frame(1, 10.01))
    (c,) = _json.loads(published[0])["cavs"]                 # strict JSON: no NaN tokens
    assert c["confidence"] == 0.8 and c["ambiguity"] is None
    assert c["covariance"][0][0] == 0.04 and c["covariance"][2][2] is None
    assert node.summary()["links"]["cav1"]["confidence"] == 0.8
    node2 = Node(_cfg(), FAKE, default_camera(), 0.7, publish=lambda k, d: published.append(d))
    node2.on_shared("cav1", _cav_bytes("cav1", 1, 10.0))
    node2.process(_frame(1, 10.01))                          # a result without those fields
    (c,) = _json.loads(published[1])["cavs"]
    assert c["confidence"] is None and c["covariance"] is None


def test_deferred_work_runs_once_per_frame_after_the_result_is_published():
    """The pipeline's idle work (the tracker's deferred search) runs after the fused result is
    published and counts nothing toward that result's latency."""
    import dataclasses
    import time

    events: list[str] = []

    def idle():
        events.append("idle")
        time.sleep(0.03)

    pipe = dataclasses.replace(FAKE, idle=idle)
    node = Node(_cfg(), pipe, default_camera(), 0.7, publish=lambda k, d: events.append(k))
    node.on_shared("cav1", _cav_bytes("cav1", 0, 10.0))
    msgs = [node.process(_frame(1, 10.02)), node.process(_frame(2, 10.07))]
    fused = keys.fused("ego1")
    assert events == [fused, "idle", fused, "idle"]
    # pairing to publish, on the second frame (the first pays one-off imports): the 30 ms of
    # idle work is not in it
    assert msgs[1]["latency_ms"] - msgs[1]["timings_ms"]["lag:paired"] < 25.0
