"""Done-when: two `mmatch run` processes (CAV and Ego, simulated sensors) over Zenoh on 127.0.0.1.

One live session (module fixture) serves several checks: fused results at 20 Hz within
50 ms, the CAV SIGKILLed and restarted (gap flagged, fusion back within 1 s), the
SIGKILLed CAV's log replays, and the Ego's clean log replays to the same fused results.
A test-side Zenoh peer watches what the vehicles publish, with its own clock.
"""

from __future__ import annotations

import json
import signal
import threading
import time

import numpy as np
import pytest
from edge_proc import dev_verifier, mmatch, pinned_time_offset, start, stop, wait_for, write_vehicle_cfg

from mmatch.edge import keys
from mmatch.edge.config import ZenohSection
from mmatch.edge.transport import Transport
from netutil import free_port

pytestmark = pytest.mark.slow

RATE = 20.0
WINDOW_S = 6.0
EPISODE = 12  # the worlds of seed 1 easy the vehicles drive (12-14; 12 and 13 fuse 96 and 100 % of
# their frames offline, where 4, the one after the 3 used before, fuses 6 %: a window crossing
# into it measured the world, not the service)



class Watcher:
    """A Zenoh peer recording (arrival time, message) of the Ego's fused results and the
    arrival times of the CAV's shared frames."""

    def __init__(self, dev_dir) -> None:
        self.dev_dir = dev_dir
        self.verifier = None
        self.fused: list[tuple[float, dict]] = []
        self.shared: list[float] = []
        self.health: list[dict] = []
        self.lock = threading.Lock()

    def open(self, vehicle: str, kind: str, payload: bytes) -> dict:
        """Signed by the vehicle's dev key, or refused (Rejected)."""
        if self.verifier is None:
            self.verifier = dev_verifier(self.dev_dir)
        return self.verifier.open_message(vehicle, kind, payload)

    def on_fused(self, vehicle: str, payload: bytes) -> None:
        t = time.time()
        msg = self.open(vehicle, "fused", payload)
        with self.lock:
            self.fused.append((t, msg))

    def on_shared(self, vehicle: str, payload: bytes) -> None:
        t = time.time()
        with self.lock:
            self.shared.append(t)

    def on_health(self, vehicle: str, payload: bytes) -> None:
        msg = self.open(vehicle, "health", payload)
        with self.lock:
            self.health.append(msg)

    def fused_since(self, t0: float) -> list[tuple[float, dict]]:
        with self.lock:
            return [(t, m) for t, m in self.fused if t >= t0]


@pytest.fixture(scope="module")
def live(tmp_path_factory):
    tmp = tmp_path_factory.mktemp("e2e")
    p_ego, p_obs = free_port(), free_port()
    ego_ep, obs_ep = f"tcp/127.0.0.1:{p_ego}", f"tcp/127.0.0.1:{p_obs}"
    off = pinned_time_offset(EPISODE)
    ego_cfg = write_vehicle_cfg(tmp / "ego.toml", vid="ego1", role="ego", listen=[ego_ep], connect=[],
                                log_dir=tmp / "log-ego", phase=0.02, cavs=["cav1"], time_offset=off)
    cav_cfgs = [write_vehicle_cfg(tmp / f"cav{k}.toml", vid="cav1", role="cav", listen=[],
                                  connect=[ego_ep, obs_ep], log_dir=tmp / f"log-cav-{k}", time_offset=off)
                for k in (1, 2)]
    w = Watcher(tmp / "dev-keys")
    out: dict = {"tmp": tmp, "watcher": w}
    procs = []
    with Transport(ZenohSection(listen=[obs_ep], connect=[ego_ep])) as obs:
        ego = start(["run", "-c", str(ego_cfg)], tmp / "ego.out")
        procs.append(ego)
        try:
            assert wait_for(lambda: obs.wait_for_peers(0.05), 30), "watcher never reached the Ego"
            obs.subscribe(keys.fused("ego1"), "fused", w.on_fused)
            obs.subscribe(keys.shared("cav1"), "shared", w.on_shared)
            obs.subscribe(keys.health("ego1"), "health", w.on_health)
            cav = start(["run", "-c", str(cav_cfgs[0])], tmp / "cav1.out")
            procs.append(cav)
            assert wait_for(lambda: any(m["cavs"] for _, m in w.fused_since(0)), 40), \
                "the Ego never fused: " + (tmp / "ego.out").read_text()[-2000:]
            time.sleep(2.0)  # settle: both processes past their first frames
            t_meas = time.time()
            time.sleep(WINDOW_S)
            out["steady"] = [(t, m) for t, m in w.fused_since(t_meas) if m["stamp"] >= t_meas]
            # the CAV dies without a word
            t_kill = time.time()
            stop(cav, signal.SIGKILL)
            out["cav_killed_rc"] = cav.returncode
            time.sleep(2.0)
            out["t_kill"] = t_kill
            t_restart = time.time()
            n_shared_before = len(w.shared)
            cav2 = start(["run", "-c", str(cav_cfgs[1])], tmp / "cav2.out")
            procs.append(cav2)
            assert wait_for(lambda: len(w.shared) > n_shared_before, 30), "restarted CAV never published"
            t_return = w.shared[n_shared_before]
            out.update(t_restart=t_restart, t_return=t_return)
            assert wait_for(lambda: any(m["cavs"] for _, m in w.fused_since(t_return)), 10)
            time.sleep(1.0)
            out["ego_alive"] = ego.poll() is None
            out["ego_rc"] = stop(ego, signal.SIGTERM)
            out["cav2_rc"] = stop(cav2, signal.SIGTERM)
        finally:
            for p in procs:
                stop(p, signal.SIGKILL)
    out["all"] = list(w.fused)
    return out


def test_ego_fuses_95_percent_of_its_frames_within_50ms(live):
    steady = live["steady"]
    stamps = np.array(sorted(m["stamp"] for _, m in steady))
    expected = int(round((stamps[-1] - stamps[0]) * RATE)) + 1
    assert expected >= 0.9 * WINDOW_S * RATE
    # a result for every frame: the CAV frame paired and either a transform estimated (from
    # matching, or from the track when a frame has nothing to match) or "no estimate" with the
    # reason when the Ego is not sure (issue 11), published within 50 ms of the own capture:
    # the Ego's own capture-to-publish time (latency_ms), not the watcher's arrival time, which
    # adds the watcher's own scheduling in this test process
    good = [m for t, m in steady if m["status"] in ("fused", "no-estimate") and m["cavs"]
            and m["latency_ms"] <= 50.0]
    fused = [m for m in good if m["status"] == "fused"]
    # which frames of the drive the window holds decides the share: 80-96 of 120 run alone
    # (2026-12-07, with the tracking of before and after that morning's changes), 63 once in a
    # clean-clone CI run; a service that fuses at all stays above half, a broken one near none
    assert len(fused) >= 0.5 * len(good)
    lat = np.array([m["latency_ms"] for _, m in steady])
    arrival = np.array([(t - m["stamp"]) * 1e3 for t, m in steady])
    print(f"steady: {len(steady)} results / {expected} frames, fused+<=50ms {len(good)}, "
          f"status fused {sum(m['status'] == 'fused' for _, m in steady)}, "
          f"latency ms median {np.median(lat):.1f} p95 {np.percentile(lat, 95):.1f} max {lat.max():.1f}, "
          f"arrival ms median {np.median(arrival):.1f} p95 {np.percentile(arrival, 95):.1f}")
    assert len(good) >= 0.95 * expected
    # the result carries what was fused with what
    m = fused[0]
    assert m["cavs"][0]["id"] == "cav1" and abs(m["cavs"][0]["dt"]) <= 0.06
    assert m["status"] == "fused" and m["links"] == {"cav1": "up"} and m["cavs"][0]["T_ego_cav"]
    # health summaries on mmatch/v1/ego1/health: rates and drops
    h = live["watcher"].health
    assert h and any(x["rates"]["frames"] > 15 for x in h) and "radar_queue" in h[-1]["drops"]


def test_cav_loss_is_flagged_and_fusion_returns_within_1s(live):
    assert live["ego_alive"] and live["ego_rc"] == 0 and live["cav2_rc"] == 0
    t_kill, t_restart, t_return = live["t_kill"], live["t_restart"], live["t_return"]
    gap = [m for t, m in live["all"] if t_kill + 0.8 <= m["stamp"] <= t_restart]
    # the Ego kept publishing its own perception at its frame rate, flagged single-vehicle
    assert len(gap) >= 0.9 * (t_restart - t_kill - 0.8) * RATE
    assert all(m["single_vehicle"] and m["gap"] and m["links"]["cav1"] == "lost" and not m["cavs"]
               for m in gap)
    back = [t for t, m in live["all"] if t >= t_return and m["cavs"]]
    print(f"fusion back {back[0] - t_return:.3f} s after the CAV's first frame")
    assert back[0] - t_return <= 1.0


def test_sigkilled_run_leaves_a_replayable_log(live):
    logdir = live["tmp"] / "log-cav-1"
    assert live["cav_killed_rc"] == -signal.SIGKILL
    res = mmatch(["replay", str(logdir), "--fast"])
    assert res.returncode == 0, res.stderr
    summary = json.loads(res.stdout)
    assert summary["truncated"], "a SIGKILLed log has no footer; the reader must say where it stopped"
    # it ran ~7 s at 20 Hz; at most the last chunk (<= 0.2 s of data) may be missing
    assert summary["frames"] >= 0.8 * 6.0 * RATE
    assert summary["node"]["frames"] == summary["frames"]


def test_replaying_the_clean_ego_log_reproduces_the_live_results(live):
    logdir = live["tmp"] / "log-ego"
    out = live["tmp"] / "replayed.jsonl"
    res = mmatch(["replay", str(logdir), "--fast", "--compare", "--fused-out", str(out)], timeout=120)
    summary = json.loads(res.stdout)
    cmp = summary["compare"]
    assert res.returncode == 0, (cmp, res.stderr[-2000:])
    assert summary["truncated"] == []
    assert cmp["recorded"] >= 200 and cmp["same"] == cmp["recorded"] and not cmp["differ"]
    replayed = [json.loads(x) for x in out.read_text().splitlines()]
    assert sum(bool(m["cavs"]) for m in replayed) >= 100
    assert sum(m["single_vehicle"] for m in replayed) >= 20  # the gap is in the log too


def test_ego_fuses_several_cavs_at_once(tmp_path):
    from mmatch.edge import logreader

    ego_ep = f"tcp/127.0.0.1:{free_port()}"
    # a function check: no frame budget (on a starved machine it would leave the second CAV out)
    off = pinned_time_offset(EPISODE)
    ego_cfg = write_vehicle_cfg(tmp_path / "ego.toml", vid="ego1", role="ego", listen=[ego_ep], connect=[],
                                log_dir=tmp_path / "log-ego", phase=0.02, cavs=[],
                                ego="frame_budget_s = 10.0", time_offset=off)
    cavs = [write_vehicle_cfg(tmp_path / f"{c}.toml", vid=c, role="cav", listen=[], connect=[ego_ep],
                              log_dir=None, phase=ph, time_offset=off)
            for c, ph in (("cav1", 0.0), ("cav2", 0.01))]
    procs = [start(["run", "-c", str(ego_cfg)], tmp_path / "ego.out")]
    try:
        procs += [start(["run", "-c", str(c)], tmp_path / f"{c.stem}.out") for c in cavs]

        def both_seen() -> bool:
            return "link to cav1 up" in (tmp_path / "ego.out").read_text() and \
                "link to cav2 up" in (tmp_path / "ego.out").read_text()

        assert wait_for(both_seen, 40), (tmp_path / "ego.out").read_text()[-2000:]
        time.sleep(4.0)
        for p in procs[1:]:
            assert stop(p) == 0
        assert stop(procs[0]) == 0
    finally:
        for p in procs:
            stop(p, signal.SIGKILL)
    msgs = [json.loads(m.data) for m in logreader.read_messages(tmp_path / "log-ego", topics=["/fused"])]
    with_both = [m for m in msgs if {c["id"] for c in m["cavs"]} == {"cav1", "cav2"}]
    # a function check, not a timing one: under CPU load a late CAV frame pairs only the other
    assert len(with_both) >= 0.5 * 4.0 * RATE
    m = with_both[-1]
    assert set(m["links"]) == {"cav1", "cav2"}
    assert all(abs(c["dt"]) <= 0.06 for c in m["cavs"])
