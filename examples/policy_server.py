"""A complete robobpp/1 policy server: lowest, then back-left placement. Run it, then evaluate it:

python examples/policy_server.py            # serves on http://127.0.0.1:9000
robobpp evaluate --policy http://127.0.0.1:9000 --dataset diverse --setting math
"""

import numpy as np

from robobpp.client import serve
from robobpp.core import Action, Observation, drop_height_map


class LowestFirst:
    name = "lowest-first"

    def act(self, obs: Observation) -> Action | None:
        best = None
        for o in obs.orientations:
            length, width, height = obs.box.dims(o)
            z = drop_height_map(obs.heightmap, length, width)  # resting height at every integer (x, y)
            z = np.where(z + height <= obs.container.height, z, np.inf)
            if z.size == 0:  # the box does not fit the footprint in this orientation
                continue
            x, y = np.unravel_index(np.argmin(z), z.shape)
            if np.isfinite(z[x, y]) and (best is None or z[x, y] < best[0]):
                best = (z[x, y], float(x), float(y), o)
        return None if best is None else Action(best[1], best[2], best[3])


if __name__ == "__main__":
    serve(LowestFirst(), port=9000)
