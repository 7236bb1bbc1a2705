"""The benchmark's evaluation maths, from episodes to boards, free of storage and transport.

One way down: ``boards`` (who is ranked, each board and the overall grid) uses ``scores`` (the paper's
weighted min–max score, the stable score, their bootstrap intervals), which uses ``stats`` (per-group
figures, the shared resample plan, intervals), which uses ``metrics`` (the eight metrics: definitions,
per-episode readings, run aggregation). The server, the CLI and the benches all score through here, so a
figure means the same wherever it is shown.
"""
