"""Dev-only: compute the PCT reference outputs that tests/policies/test_pct_network.py checks us against.

How the fixture was made (run once; needs PyTorch, which robobpp itself never needs)::

    pip install torch                      # CPU build is enough
    git clone https://github.com/alexfrom0815/Online-3D-BPP-PCT /path/to/pct
    python tools/make_pct_fixture.py --pct-repo /path/to/pct

It builds the authors' own network class (``DRL_GAT`` from the PCT repository, imported from the
clone, not rewritten), loads the weights from the packsim wheel of the datasets cache the way packsim's
``load_policy`` does (key renames, ``torch.load``, the file's sha256 checked first), and runs it on fixed
inputs: the tree nodes our ``leaves.build_nodes`` produces at a few steps of real Repetitive train episodes,
plus two synthetic node sets. It writes ``tests/policies/data/pct_reference.npz``: the inputs (the
reference's (131, 9) node layout), the normalisation factor, and the reference's leaf probabilities,
greedy leaf and critic value for each.
"""

from __future__ import annotations

import argparse
import sys
import types
from pathlib import Path

import numpy as np

OUT = Path(__file__).resolve().parents[1] / "tests" / "policies" / "data" / "pct_reference.npz"


def reference_model(repo: Path):  # noqa: ANN201 - torch types are dev-only
    import torch

    # The repository's tools.py registers gym envs at import; the network needs none of that.
    gym = types.ModuleType("gym")
    gym.envs = types.ModuleType("gym.envs")  # type: ignore[attr-defined]
    gym.envs.registration = types.SimpleNamespace(register=lambda **_: None)  # type: ignore[attr-defined]
    sys.modules.update({"gym": gym, "gym.envs": gym.envs, "gym.envs.registration": gym.envs.registration})
    sys.path.insert(0, str(repo))
    # attention_model.py calls super() inside a NamedTuple, which Python >= 3.11 refuses at class creation;
    # that method (tuple indexing) is unused here, so the one call is rewritten in memory before import.
    source = (repo / "attention_model.py").read_text()
    source = source.replace(
        "super(AttentionModelFixed, self).__getitem__(key)", "tuple.__getitem__(self, key)"
    )
    module = types.ModuleType("attention_model")
    module.__file__ = str(repo / "attention_model.py")
    sys.modules["attention_model"] = module
    exec(compile(source, module.__file__, "exec"), module.__dict__)  # noqa: S102 - the authors' code, dev only
    from model import DRL_GAT  # the authors' class

    from robobpp.policies.pct.checkpoint import cached_wheel, read_weights_bytes

    args = types.SimpleNamespace(
        embedding_size=64,
        hidden_size=128,
        gat_layer_num=1,
        internal_node_holder=80,
        internal_node_length=6,
        leaf_node_holder=50,
    )  # fmt: skip  (packsim/packer/pct.yaml)
    model = DRL_GAT(args)
    import io

    raw = torch.load(io.BytesIO(read_weights_bytes(cached_wheel())), map_location="cpu", weights_only=True)
    state = {}
    for key, value in raw.items():  # the renames of packsim's load_policy
        key = (
            key.replace("module.weight", "weight")
            if "actor.embedder.layers" in key
            else key.replace("module.", "")
        )
        key = key.replace("add_bias.", "").replace("_bias", "bias")
        state[key] = value.squeeze(-1) if value.dim() <= 3 else value
    model.load_state_dict(state, strict=True)
    model.eval()
    return model


def node_sets() -> list[tuple[np.ndarray, float]]:
    """(131, 9) node arrays: real states from our node builder, then two synthetic ones."""
    from robobpp.core import EpisodeInfo
    from robobpp.datasets import episode_specs
    from robobpp.episode import Episode
    from robobpp.policies.pct import PCT
    from robobpp.policies.pct.leaves import build_nodes

    out = []
    spec = episode_specs("repetitive", split="train", groups=1, seed=0)[0]
    policy = PCT()
    policy.reset(EpisodeInfo(spec.episode_id, spec.dataset, "math", spec.container))
    episode = Episode(spec, "math")
    norm = 1.0 / max(spec.container.length, spec.container.width, spec.container.height)
    step = 0
    while not episode.done and step <= 40:
        obs = episode.observe()
        if step in (0, 12, 40):
            nodes = build_nodes(obs, policy._tracker.sync(obs.placed), np.random.default_rng(step))  # type: ignore[union-attr]
            out.append((stack(nodes), norm))
        action = policy.act(obs)
        if action is None:
            break
        episode.step(action, decision_time=0.0)
        step += 1
    rng = np.random.default_rng(7)
    for valid_leaves in (50, 3):
        nodes = np.zeros((131, 9))
        nodes[:30, :6] = rng.uniform(0, 100, (30, 6))
        nodes[:30, 8] = 1
        nodes[80 : 80 + valid_leaves, :8] = rng.uniform(0, 100, (valid_leaves, 8))
        nodes[80 : 80 + valid_leaves, 8] = 1
        nodes[130, :6] = (1, 0, 0, 20, 30, 40)
        nodes[130, 8] = 1
        out.append((nodes, 1.0 / 134))
    return out


def stack(nodes) -> np.ndarray:  # noqa: ANN001
    array = np.zeros((131, 9))
    array[:80, :6], array[:80, 8] = nodes.internal, nodes.internal_valid
    array[80:130, :8], array[80:130, 8] = nodes.leaves, nodes.leaf_valid
    array[130, :6], array[130, 8] = nodes.next_item, 1
    return array


def main() -> None:
    parser = argparse.ArgumentParser(
        description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    parser.add_argument(
        "--pct-repo", type=Path, required=True, help="a clone of alexfrom0815/Online-3D-BPP-PCT"
    )
    args = parser.parse_args()
    import torch

    model = reference_model(args.pct_repo)
    cases = node_sets()
    inputs = np.stack([c[0] for c in cases]).astype(np.float32)
    norms = np.array([c[1] for c in cases], np.float32)
    probs, choices, values = [], [], []
    with torch.no_grad():
        for nodes, norm in zip(inputs, norms, strict=True):
            x = torch.from_numpy(nodes)[None]
            _, pointer, _, hidden, dist = model.actor(x, deterministic=True, normFactor=float(norm))
            probs.append(dist.probs[0].numpy())
            choices.append(int(pointer[0, 0]))
            values.append(float(model.critic(hidden)[0, 0]))
    OUT.parent.mkdir(parents=True, exist_ok=True)
    np.savez_compressed(OUT, nodes=inputs, norm=norms, probs=np.stack(probs), choice=np.array(choices),
                        value=np.array(values, np.float32))  # fmt: skip
    print(f"wrote {OUT.name}: {len(cases)} cases, choices {choices}, values {np.round(values, 4).tolist()}")


if __name__ == "__main__":
    main()
