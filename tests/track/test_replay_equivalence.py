"""The live path is the evaluated path: a drive of scene files played live by two vehicle services
(`radar.source = "scene"`, Zenoh on 127.0.0.1, signed frames), the Ego's log replayed through
`mmatch replay`, gives bit for bit what `mmatch eval --sequences` gives on the same files."""

from __future__ import annotations

import json
import subprocess
import sys
import time
from pathlib import Path

from mmatch.edge.cli import main
from mmatch.sim.generate import generate_sequences
from netutil import free_port

REPO = Path(__file__).resolve().parents[2]
FRAMES = 16


def _service(cfg: str, sets: list[str], out: Path) -> subprocess.Popen:
    args = [sys.executable, "-m", "mmatch.edge.cli", "run", "-c", str(REPO / "cfg" / cfg)]
    for s in sets:
        args += ["--set", s]
    return subprocess.Popen(args, stdout=open(out, "w"), stderr=subprocess.STDOUT, cwd=out.parent)


def test_eval_sequences_replays_bit_identically_through_a_log_of_a_live_run(tmp_path, capsys):
    drive = tmp_path / "drive"
    generate_sequences(drive, 1, FRAMES, seed=77, mode="hard", physics="wide")
    ep = f"tcp/127.0.0.1:{free_port()}"
    common = [f'scene.path="{drive}"', f"scene.start={time.time() + 6.0:.3f}", f'auth.dev_dir="{tmp_path / "keys"}"']
    ego = _service("vehicle-ego-scene.toml", common + [f'zenoh.listen=["{ep}"]', f'log.dir="{tmp_path / "log"}"'],
                   tmp_path / "ego.out")
    cav = _service("vehicle-cav-scene.toml", common + [f'zenoh.connect=["{ep}"]'], tmp_path / "cav.out")
    try:
        assert cav.wait(120) == 0, (tmp_path / "cav.out").read_text()[-3000:]
        assert ego.wait(120) == 0, (tmp_path / "ego.out").read_text()[-3000:]
    finally:
        for p in (ego, cav):
            if p.poll() is None:
                p.kill()
                p.wait()
    assert main(["eval", str(drive), "--sequences", "--json", str(tmp_path / "eval.json")]) == 0
    capsys.readouterr()
    code = main(["replay", str(tmp_path / "log"), "--fast", "--compare", "--compare-eval", str(tmp_path / "eval.json"),
                 "--fused-out", str(tmp_path / "replayed.jsonl")])
    summary = json.loads(capsys.readouterr().out)
    assert summary["compare"]["match"], summary["compare"]                  # the replay is the live run
    cmp = summary["compare_eval"]
    assert cmp["frames"] == FRAMES and cmp["same"] == FRAMES and code == 0, cmp   # and the evaluation
    # not vacuous: transforms, objects with track ids and tracks were compared
    msgs = [json.loads(line) for line in (tmp_path / "replayed.jsonl").read_text().splitlines()]
    assert sum(m["status"] == "fused" for m in msgs) >= FRAMES // 2
    assert all(len(o) == 5 for m in msgs for o in m["objects"]) and sum(len(m["tracks"]) for m in msgs) > FRAMES
    # and a difference is found: one replayed transform moved by a micrometre
    rows = json.loads((tmp_path / "eval.frames.json").read_text())
    k = next(i for i, r in enumerate(rows["tracked"]) if r["T_ego_cav"] is not None)
    rows["tracked"][k]["T_ego_cav"][0][3] += 1e-6
    (tmp_path / "moved.frames.json").write_text(json.dumps(rows))
    assert main(["replay", str(tmp_path / "log"), "--fast", "--compare-eval", str(tmp_path / "moved.frames.json")]) == 1
    moved = json.loads(capsys.readouterr().out)["compare_eval"]
    assert moved["differ"] == [{"frame": rows["tracked"][k]["frame"], "fields": ["T_ego_cav"]}]
