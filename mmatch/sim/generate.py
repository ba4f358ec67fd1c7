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


def _one_sequence(args: tuple[str, int, int, int, str, str]) -> list[Scene]:
    from mmatch.sim.sequences import make_sequence
    out, seed, index, frames, mode, physics = args
    seq = make_sequence(seed, index, frames, mode, physics)
    scenes = []
    for k in range(frames):
        scene = seq.scene(k)
        save_scene(Path(out) / f"{scene.name}.npz", scene)
        scenes.append(scene)
    return scenes


def generate_sequences(out: str | Path, sequences: int, frames: int, seed: int, mode: str, jobs: int = 1,
                       progress: Callable[[int, int], None] | None = None,
                       physics: str = "nominal") -> list[Scene]:
    """Simulate `sequences` drives of `frames` frame pairs each (mmatch/sim/sequences.py) into
    folder `out` as `<sequence>_<frame:05d>.npz` (DESIGN.md "Sequences"); the physics is drawn
    once per sequence. Returns every frame, sequence after sequence."""
    from mmatch.sim.physics import family
    family(physics)
    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    tasks = [(str(out), seed, i, frames, mode, str(physics)) for i in range(sequences)]
    scenes: list[Scene] = []
    if jobs <= 1:
        results = map(_one_sequence, tasks)
        for k, seq in enumerate(results):
            scenes.extend(seq)
            if progress:
                progress(k + 1, sequences)
        return scenes
    with ProcessPoolExecutor(max_workers=jobs) as pool:
        for k, seq in enumerate(pool.map(_one_sequence, tasks)):
            scenes.extend(seq)
            if progress:
                progress(k + 1, sequences)
    return scenes
