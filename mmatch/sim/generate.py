"""Write a simulated data set of `mmatch-scene/1` files, optionally on several cores."""

from __future__ import annotations

from collections.abc import Callable
from concurrent.futures import ProcessPoolExecutor
from pathlib import Path

from mmatch.scene_io import save_scene
from mmatch.sim.scenario import make_scene
from mmatch.types import Scene


def _one(args: tuple[str, int, int, str, str]) -> Scene:
    out, seed, index, mode, physics = args
    scene = make_scene(seed, index, mode, physics)
    save_scene(Path(out) / f"{scene.name}.npz", scene)
    return scene


def generate(out: str | Path, n: int, seed: int, mode: str, jobs: int = 1,
             progress: Callable[[int, int], None] | None = None, physics: str = "nominal") -> list[Scene]:
    """Simulate `n` scenes of `mode` from `seed` into folder `out` under `physics` (nominal, wide
    or a TOML file of ranges, see sim/physics.py); returns them in index order."""
    from mmatch.sim.physics import family
    family(physics)                                   # a bad physics file fails here, naming the key
    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    tasks = [(str(out), seed, i, mode, str(physics)) for i in range(n)]
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
