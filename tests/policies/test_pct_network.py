"""PCT's numpy forward pass against the authors' PyTorch network, and the safe weights reader.

The expected outputs were computed once by ``tools/make_pct_fixture.py`` (the authors' ``DRL_GAT`` class,
PyTorch, the same weights); see its docstring for how to regenerate them.
"""

import io
import pickle
import zipfile
from pathlib import Path

import numpy as np
import pytest

from robobpp.policies.pct.checkpoint import CheckpointError, read_state_dict, read_weights_bytes
from robobpp.policies.pct.network import PCTNetwork

FIXTURE = Path(__file__).parent / "data" / "pct_reference.npz"


@pytest.fixture
def weights(real_data):
    from robobpp.policies.pct.checkpoint import load_weights

    return load_weights()


@pytest.mark.network
def test_forward_pass_reproduces_the_reference_network(weights):
    net = PCTNetwork(weights)
    ref = np.load(FIXTURE)
    for nodes, norm, probs, choice, value in zip(
        ref["nodes"], ref["norm"], ref["probs"], ref["choice"], ref["value"], strict=True
    ):
        out = net(
            nodes[:80, :6], nodes[80:130, :8], nodes[130, :6], nodes[:80, 8] > 0, nodes[80:130, 8] > 0, norm
        )
        np.testing.assert_allclose(out.probs, probs, rtol=1e-4, atol=1e-7)  # float32 rounding
        assert out.choice == choice
        assert out.value == pytest.approx(float(value), abs=1e-4)
    assert len(set(ref["choice"].tolist())) > 1  # the cases do not all pick the same leaf


def _checkpoint(payload: bytes, storages: dict[str, bytes] | None = None) -> bytes:
    buf = io.BytesIO()
    with zipfile.ZipFile(buf, "w") as z:
        z.writestr("ckpt/data.pkl", payload)
        for key, raw in (storages or {}).items():
            z.writestr(f"ckpt/data/{key}", raw)
    return buf.getvalue()


class _Evil:
    def __reduce__(self):
        import os

        return (os.system, ("echo pwned",))


def test_reader_refuses_a_pickle_that_would_run_code():
    with pytest.raises(CheckpointError, match=r"refusing to load (posix|os|nt)\.system"):
        read_state_dict(_checkpoint(pickle.dumps({"w": _Evil()}, protocol=2)))


def test_reader_rebuilds_tensors_from_storages():
    # The pickle torch writes for {"w": a 2x3 float tensor viewing storage "0" with stride (3, 1)}
    class Storage:  # pickled by name as torch.FloatStorage
        pass

    Storage.__module__, Storage.__qualname__ = "torch", "FloatStorage"

    class Rebuild:
        def __reduce__(self):
            return (_rebuild, ((("storage", Storage, "0", "cpu", 6)), 0, (2, 3), (3, 1), False, {}))

    def _rebuild(*args):  # stands in for torch._utils._rebuild_tensor_v2 while pickling
        return None

    _rebuild.__module__, _rebuild.__qualname__ = "torch._utils", "_rebuild_tensor_v2"

    class P(pickle.Pickler):
        def persistent_id(self, obj):
            return obj if isinstance(obj, tuple) and obj and obj[0] == "storage" else None

    import sys
    import types

    fake = types.ModuleType("torch._utils")
    vars(fake).update(_rebuild_tensor_v2=_rebuild)
    torch_mod = types.ModuleType("torch")
    vars(torch_mod).update(FloatStorage=Storage)
    saved = {k: sys.modules.get(k) for k in ("torch", "torch._utils")}
    sys.modules.update({"torch": torch_mod, "torch._utils": fake})
    try:
        buf = io.BytesIO()
        P(buf, protocol=2).dump({"w": Rebuild()})
    finally:
        for k, v in saved.items():
            if v is None:
                sys.modules.pop(k, None)
            else:
                sys.modules[k] = v
    raw = np.arange(6, dtype="<f4").tobytes()
    state = read_state_dict(_checkpoint(buf.getvalue(), {"0": raw}))
    np.testing.assert_array_equal(state["w"], np.arange(6, dtype=np.float32).reshape(2, 3))
    with pytest.raises(CheckpointError, match="6"):  # a storage shorter than the pickle says
        read_state_dict(_checkpoint(buf.getvalue(), {"0": raw[:8]}))


def test_altered_weights_are_refused(tmp_path):
    wheel = tmp_path / "packsim.whl"
    with zipfile.ZipFile(wheel, "w") as z:
        z.writestr("packsim/packer/pct.pt", b"not the authors' weights")
    with pytest.raises(CheckpointError, match="sha256 mismatch"):
        read_weights_bytes(wheel)
    with zipfile.ZipFile(wheel, "w") as z:
        z.writestr("packsim/other.txt", b"")
    with pytest.raises(CheckpointError, match="has no packsim/packer/pct.pt"):
        read_weights_bytes(wheel)
