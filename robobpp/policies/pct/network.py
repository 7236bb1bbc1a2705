"""The PCT actor–critic forward pass in numpy (float32), for the authors' trained weights.

The network (Zhao et al., "Learning Efficient Online 3D Bin Packing on Packing Configuration Trees",
ICLR 2022) embeds three kinds of nodes with three small MLPs: *internal* nodes (placed boxes, 6 numbers),
*leaf* nodes (candidate placements for the current box, 8 numbers) and the *next* item (6 numbers). One
graph-attention layer (one head, skip connections, no normalisation) mixes them; the mean over the valid
nodes, projected, is the query of a pointer over the leaf nodes (tanh-clipped at 10, softmax), and the
critic's input. Invalid nodes are padding: they are masked as attention keys and left out of the mean.

Our arrays mirror the reference's arithmetic step by step (including the −30 attention mask and the
post-softmax zeroing of masked weights) so its outputs are reproduced to float32 rounding; the test
``tests/policies/test_pct_network.py`` checks that against outputs computed with PyTorch.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

EMBED = 64
TANH_CLIP = 10.0
#: The reference masks attention to padding nodes with −30 before the softmax (its training-time value).
MASKED_COMPAT = -30.0


@dataclass(frozen=True, slots=True)
class Linear:
    weight: np.ndarray  # (out, in)
    bias: np.ndarray | None  # (out,)

    def __call__(self, x: np.ndarray) -> np.ndarray:
        y = x @ self.weight.T
        out: np.ndarray = y if self.bias is None else y + self.bias
        return out


def _leaky_relu(x: np.ndarray) -> np.ndarray:
    return np.where(x > 0, x, np.float32(0.01) * x)


@dataclass(frozen=True, slots=True)
class MLP:
    first: Linear
    second: Linear

    def __call__(self, x: np.ndarray) -> np.ndarray:
        return self.second(_leaky_relu(self.first(x)))


@dataclass(frozen=True, slots=True)
class PCTOutput:
    """One forward pass: leaf probabilities (masked, renormalised), the greedy leaf, the critic's value."""

    probs: np.ndarray  # (leaves,)
    choice: int
    value: float


class PCTNetwork:
    """``PCTNetwork(state_dict)(internal, leaves, nxt, internal_valid, leaf_valid, norm)``."""

    def __init__(self, state: dict[str, np.ndarray]) -> None:
        def lin(prefix: str, bias: bool = True) -> Linear:
            # The authors wrap each Linear in an init helper: weights under ``module.``, bias under ``add_bias._bias``.
            weight = state.get(f"{prefix}.module.weight", state.get(f"{prefix}.weight"))
            if weight is None:
                raise KeyError(f"PCT weights lack {prefix}.weight")
            b = state.get(f"{prefix}.add_bias._bias", state.get(f"{prefix}.bias")) if bias else None
            return Linear(weight, None if b is None else b.reshape(-1))

        def mlp(name: str) -> MLP:
            return MLP(lin(f"actor.{name}.0"), lin(f"actor.{name}.2"))

        layer = "actor.embedder.layers.0"
        self.internal_embed = mlp("init_internal_node_embed")
        self.leaf_embed = mlp("init_leaf_node_embed")
        self.next_embed = mlp("init_next_embed")
        self.w_query = lin(f"{layer}.0.module.W_query", bias=False)
        self.w_key = lin(f"{layer}.0.module.W_key", bias=False)
        self.w_val = lin(f"{layer}.0.module.W_val", bias=False)
        self.w_out = lin(f"{layer}.0.module.W_out")
        self.ff_in = lin(f"{layer}.1.module.0")
        self.ff_out = lin(f"{layer}.1.module.2")
        self.project_nodes = lin("actor.project_node_embeddings", bias=False)
        self.project_context = lin("actor.project_fixed_context", bias=False)
        self.critic = lin("critic")
        self.internal_length = self.internal_embed.first.weight.shape[1]
        self.leaf_length = self.leaf_embed.first.weight.shape[1]
        self.next_length = self.next_embed.first.weight.shape[1]

    def __call__(
        self,
        internal: np.ndarray,
        leaves: np.ndarray,
        nxt: np.ndarray,
        internal_valid: np.ndarray,
        leaf_valid: np.ndarray,
        norm: float,
    ) -> PCTOutput:
        """Score the leaves. Shapes: (I, 6), (L, 8), (6,), (I,), (L,); ``norm`` = 1 / the largest container side."""
        f = np.float32(norm)
        h = np.concatenate(
            [
                self.internal_embed(internal.astype(np.float32) * f),
                self.leaf_embed(leaves.astype(np.float32) * f),
                self.next_embed(nxt.astype(np.float32).reshape(1, -1) * f),
            ]
        )
        valid = np.concatenate([internal_valid, leaf_valid, [True]]).astype(bool)
        # attention layer (one head): padding nodes are masked as keys, their own rows are computed and ignored
        q, k, v = self.w_query(h), self.w_key(h), self.w_val(h)
        compat = (q @ k.T) * np.float32(1.0 / np.sqrt(k.shape[1]))
        compat[:, ~valid] = MASKED_COMPAT
        compat -= compat.max(axis=1, keepdims=True)
        attn = np.exp(compat)
        attn /= attn.sum(axis=1, keepdims=True)
        attn[:, ~valid] = 0.0
        h = h + self.w_out(attn @ v)
        h = h + self.ff_out(np.maximum(self.ff_in(h), 0.0))
        # pointer decoder: the graph mean over valid nodes is the query over the leaf nodes' keys
        h[~valid] = 0.0
        context = self.project_context(h.sum(axis=0) / np.float32(valid.sum()))
        keys = self.project_nodes(h)[:, :EMBED]
        first, count = len(internal), len(leaves)
        logits = np.tanh((keys[first : first + count] @ context) / np.float32(np.sqrt(EMBED))) * TANH_CLIP
        logits -= logits.max()
        probs = np.exp(logits)
        probs /= probs.sum()
        masked = probs * leaf_valid.astype(np.float32)
        total = masked.sum()
        masked = masked / total if total > 0 else masked
        value = float(self.critic(context)[0])
        return PCTOutput(masked, int(np.argmax(masked)), value)
