"""Draw one episode's world in a separate process: `python -m mmatch.sim.worldgen SEED MODE COVISIBLE TRIES EPISODE`.

Writes the pickled `World` to stdout. The live simulator runs it ahead of time so that the
Python-heavy draw (0.1-0.5 s) never holds the interpreter lock of a vehicle's frame loop.
"""

from __future__ import annotations

import pickle
import sys


def main(argv: list[str]) -> int:
    from mmatch.sim.scenario import Scenario

    seed, mode, covisible, tries, episode = argv
    world = Scenario(int(seed), mode, covisible=int(covisible), tries=int(tries))._build(int(episode))
    sys.stdout.buffer.write(pickle.dumps(world, protocol=pickle.HIGHEST_PROTOCOL))
    return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
