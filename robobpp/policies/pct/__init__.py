"""PCT, the paper's strongest learned policy, from its authors' trained weights (numpy inference, no PyTorch).

``checkpoint`` reads the weights safely from the cached packsim wheel, ``network`` is the forward pass,
``leaves`` builds the tree's nodes (empty maximal spaces, candidate placements, features), ``policy`` is
the ``pct`` policy. See docs/baselines.md ("PCT").
"""

from robobpp.policies.pct.policy import PCT

__all__ = ["PCT"]
