"""Fake DCA1000 -> UDP 127.0.0.1 -> DataReceiver: complete frames, injected loss and reordering."""

from __future__ import annotations

import numpy as np
import pytest

from mmatch.drivers.dca1000.assembler import FrameAssembler
from mmatch.drivers.dca1000.control import Dca1000Control
from mmatch.drivers.dca1000.dsp import make_dsp
from mmatch.drivers.dca1000.fake import FakeDca1000
from mmatch.drivers.dca1000.layout import FrameGeometry, RawLayout, raw_to_cube
from mmatch.drivers.dca1000.receiver import DataReceiver
from mmatch.drivers.dca1000.synth import Target, synth_raw_frames

GEOM = FrameGeometry(RawLayout.FOUR_LANE, 16, (0, 1, 2), (0, 1, 2, 3), 64)  # 49152 B = 33.8 packets
F = GEOM.frame_bytes
NUM = 100
SRC = np.random.default_rng(11).integers(0, 256, 4 * F, dtype=np.uint8).tobytes()


def _record(loss: float = 0.0, reorder: float = 0.0, seed: int = 0):
    asm = FrameAssembler(F, num_frames=NUM)
    with (
        DataReceiver(asm, host="127.0.0.1", port=0) as rx,
        FakeDca1000(
            SRC, F, NUM, rx.address, loss=loss, reorder=reorder, seed=seed, rate_mb_s=40
        ) as fake,
        Dca1000Control(
            "127.0.0.1", fake.control_address[1], local=("127.0.0.1", 0), timeout_s=0.5
        ) as ctl,
    ):
        ctl.setup()
        ctl.start_record()
        frames = list(rx.frames(idle_timeout_s=0.5, deadline_s=30))
        ctl.stop_record()
        return frames, asm.stats, fake


def _exact(f) -> bool:
    k = f.index % 4
    return f.data.tobytes() == SRC[k * F : (k + 1) * F]


def test_every_frame_arrives_complete_and_exact():
    frames, st, fake = _record(reorder=0.02, seed=1)
    assert [f.index for f in frames] == list(range(NUM))
    assert all(f.complete and _exact(f) for f in frames)
    assert st.out_of_order > 0 and st.frames_flagged == 0 and st.bad_packets == 0
    assert st.packets == fake.num_packets


def test_one_percent_loss_flags_exactly_the_affected_frames():
    frames, st, fake = _record(loss=0.01, reorder=0.01, seed=3)
    affected = fake.affected_frames()
    assert 10 <= len(fake.dropped) <= 60 and affected  # the injection did happen
    assert {f.index for f in frames if not f.complete} == affected
    assert [f.index for f in frames] == list(range(NUM))  # nothing lost as a whole, in order
    for f in frames:
        if f.complete:
            assert _exact(f)
        else:
            k = f.index % 4
            ref = np.frombuffer(SRC[k * F : (k + 1) * F], dtype=np.uint8)
            diff = f.data != ref
            assert not f.data[diff].any() and f.missing_bytes > 0  # gaps are zero-filled
    assert st.frames_flagged == len(affected)


@pytest.mark.parametrize("policy", ["drop"])
def test_drop_policy_over_udp(policy):
    asm = FrameAssembler(F, num_frames=NUM, policy=policy)
    with (
        DataReceiver(asm, host="127.0.0.1", port=0) as rx,
        FakeDca1000(SRC, F, NUM, rx.address, loss=0.01, seed=5, rate_mb_s=40) as fake,
    ):
        fake.start_stream()
        frames = list(rx.frames(idle_timeout_s=0.5, deadline_s=30))
    affected = fake.affected_frames()
    assert {f.index for f in frames} == set(range(NUM)) - affected
    assert all(f.complete and _exact(f) for f in frames)
    assert asm.stats.frames_dropped == len(affected)


def test_synthesised_capture_end_to_end(radar_cfg):
    """3TX x 4RX frames synthesised, streamed, reassembled and processed into the right point."""
    geom, dsp = make_dsp(radar_cfg)
    t = Target(30.0, -6.0, -20.0, 0.0)
    src = synth_raw_frames(radar_cfg.chirp, geom, [t], 2)
    asm = FrameAssembler(geom.frame_bytes, num_frames=3)
    with (
        DataReceiver(asm, host="127.0.0.1", port=0) as rx,
        FakeDca1000(src, geom.frame_bytes, 3, rx.address, rate_mb_s=60) as fake,
    ):
        fake.start_stream()
        frames = list(rx.frames(idle_timeout_s=0.5, deadline_s=30))
    assert [f.index for f in frames] == [0, 1, 2] and all(f.complete for f in frames)
    for f in frames:
        pts = dsp.process(raw_to_cube(f.data, geom)).points
        assert len(pts) == 1
        r = float(np.linalg.norm(pts[0, :3]))
        assert abs(r - 30.0) < 2 * radar_cfg.chirp.range_resolution_m  # moves 0.3 m per 50-ms frame
        assert pts[0, 0] < 0 and pts[0, 3] < 0


@pytest.mark.parametrize("batch", [1, 64])
def test_receive_paths_agree_under_loss(batch):
    """One recv per datagram and recvmmsg batches give the same frames and flags."""
    asm = FrameAssembler(F, num_frames=40)
    with (
        DataReceiver(asm, host="127.0.0.1", port=0, batch=batch) as rx,
        FakeDca1000(SRC, F, 40, rx.address, loss=0.01, reorder=0.01, seed=8, rate_mb_s=40) as fake,
    ):
        fake.start_stream()
        frames = list(rx.frames(idle_timeout_s=0.5, deadline_s=30))
    assert [f.index for f in frames] == list(range(40))
    assert {f.index for f in frames if not f.complete} == fake.affected_frames() != set()
    assert all(_exact(f) for f in frames if f.complete)


@pytest.mark.parametrize("batch", [1, 64])
def test_corrupt_datagrams_flag_only_their_frame(batch):
    """A runt datagram, an oversize one and a packet with an impossible byte count."""
    import socket

    from mmatch.drivers.dca1000.protocol import data_packet

    P = 1456
    n_frames = 4
    data = SRC[: n_frames * F]
    pk = [
        data_packet(i + 1, i * P, data[i * P : (i + 1) * P].ljust(P, b"\0"))
        for i in range(-(-len(data) // P))
    ]
    bad_i = 50  # inside frame 50*P // F = 1
    pk[bad_i] = data_packet(bad_i + 1, bad_i * P + 4096, data[bad_i * P : (bad_i + 1) * P])
    pk.insert(80, b"\x01\x02\x03\x04\x05")  # runt
    pk.insert(81, data_packet(81, 80 * P, bytes(2000)))  # oversize payload
    asm = FrameAssembler(F, num_frames=n_frames)
    with (
        DataReceiver(asm, host="127.0.0.1", port=0, batch=batch) as rx,
        socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as tx,
    ):
        for d in pk:
            tx.sendto(d, rx.address)
        frames = list(rx.frames(idle_timeout_s=0.3, deadline_s=10))
    assert [f.index for f in frames] == list(range(n_frames))
    assert {f.index for f in frames if not f.complete} == {bad_i * P // F}
    assert all(_exact(f) for f in frames if f.complete)
    assert asm.stats.bad_packets == 3


def test_fake_replays_a_recorded_capture(tmp_path):
    cap = tmp_path / "adc_data_Raw_0.bin"
    cap.write_bytes(SRC[: 3 * F] + bytes(700))  # 3 frames + the FPGA's last-packet padding
    asm = FrameAssembler(F, num_frames=3)
    with (
        DataReceiver(asm, host="127.0.0.1", port=0) as rx,
        FakeDca1000.from_capture(cap, F, rx.address, rate_mb_s=40) as fake,
    ):
        assert fake.num_frames == 3
        fake.start_stream()
        frames = list(rx.frames(idle_timeout_s=0.5, deadline_s=10))
    assert [f.index for f in frames] == [0, 1, 2] and all(f.complete and _exact(f) for f in frames)


def test_small_kernel_buffer_is_reported(caplog):
    import logging

    with caplog.at_level(logging.WARNING, logger="mmatch.drivers.dca1000.receiver"):
        with DataReceiver(FrameAssembler(F), host="127.0.0.1", port=0, rcvbuf=1 << 30) as rx:
            assert 0 < rx.rcvbuf < 1 << 30
    assert "rmem_max" in caplog.text
