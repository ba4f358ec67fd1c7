"""Write a simulated data set of `mmatch-scene/1` files, optionally on several cores."""

from __future__ import annotations

from collections.abc import Callable
from concurrent.futures import ProcessPoolExecutor
from pathlib import Path

from mmatch.scene_io import save_scene
from mmatch.sim.scenario import make_scene
from mmatch.types import Scene


def _one(args: tuple[str, int, int, str]) -> Scene:
    out, seed, index, mode = args
    scene = make_scene(seed, index, mode)
    save_scene(Path(out) / f"{scene.name}.npz", scene)
    return scene


def generate(out: str | Path, n: int, seed: int, mode: str, jobs: int = 1,
             progress: Callable[[int, int], None] | None = None) -> list[Scene]:
    """Simulate `n` scenes of `mode` from `seed` into folder `out`; returns them in index order."""
    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    tasks = [(str(out), seed, i, mode) for i in range(n)]
    scenes: list[Scene] = []
    if jobs <= 1:
        for k, t in enumerate(tasks):
            scenes.append(_one(t))
            if progress:
                progress(k + 1, n)
        return scenes
    with ProcessPoolExecutor(max_workers=jobs) as pool:
        for k, scene in enumerate(pool.map(_one, tasks, chunksize=4)):
            scenes.append(scene)
            if progress:
                progress(k + 1, n)
    return scenes
