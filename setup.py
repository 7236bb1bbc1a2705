"""The one thing pyproject.toml does not declare yet (setuptools calls its table for it experimental): the
compiled steps of a board's full computation, robobpp/scoring/_kernels.c (plain C, no headers beyond
Python's). Optional: without a C compiler the package installs all the same and numpy does those steps, more
slowly (docs/server.md, "How boards are computed")."""

from setuptools import Extension, setup

setup(
    ext_modules=[
        Extension(
            "robobpp.scoring._kernels",
            sources=["robobpp/scoring/_kernels.c"],
            # -O3: the minimum and maximum fold is vectorised; no fused multiply-add: the timing noise must round
            # as numpy's separate steps do, on any machine
            extra_compile_args=["-O3", "-ffp-contract=off"],
            optional=True,
        )
    ]
)
