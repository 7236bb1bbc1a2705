"""A complete robobpp/1 policy server: lowest, then back-left placement. Run it, then evaluate it:

python examples/policy_server.py                      # serves on http://127.0.0.1:9000
robobpp evaluate --policy http://127.0.0.1:9000 --dataset diverse --setting math

``--port`` and ``--secret`` (at least 8 characters; requests must then be signed with it) are optional.
The policy class is the one the server's "Take part" page shows; a test keeps the two identical.
"""

import argparse

from robobpp.client import serve

# --- policy ---
from robobpp.core import Action, Observation
from robobpp.policies.base import BasePolicy
from robobpp.policies.candidates import candidate_maps


class LowestFirst(BasePolicy):
    """Place each box as low as possible, then as far back-left as possible."""

    name = "lowest-first"

    def act(self, obs: Observation) -> Action | None:
        best = None
        for c in candidate_maps(obs):  # one map per orientation
            z = c.z.copy()  # resting height of every (x, y)
            z[~c.fits] = float("inf")
            x, y = divmod(int(z.argmin()), z.shape[1])
            if c.fits[x, y] and (best is None or z[x, y] < best[0]):
                best = (z[x, y], x, y, c.orientation)
        return None if best is None else Action(float(best[1]), float(best[2]), best[3])


# --- end policy ---

if __name__ == "__main__":
    parser = argparse.ArgumentParser(description="Serve the LowestFirst policy (protocol robobpp/1).")
    parser.add_argument("--host", default="127.0.0.1")
    parser.add_argument("--port", type=int, default=9000)
    parser.add_argument("--secret", default=None, help="shared secret (at least 8 characters)")
    args = parser.parse_args()
    serve(LowestFirst(), host=args.host, port=args.port, secret=args.secret)
