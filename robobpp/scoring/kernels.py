"""The compiled steps of a board's full computation (``_kernels.c``: ranks, order statistics and three
element-wise passes), or None where the package was installed without a C compiler: then numpy does them, more
slowly, to the same bits (docs/server.md, "How boards are computed"). Each caller keeps numpy's way as its
reference and fallback."""

from __future__ import annotations

from types import ModuleType

compiled: ModuleType | None
try:
    from robobpp.scoring import _kernels as compiled
except ImportError:  # pragma: no cover - installed without a C compiler
    compiled = None

#: Whether they are in use (the board worker warns at its start when not; CI's tests require them).
BUILT = compiled is not None
