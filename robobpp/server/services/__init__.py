"""What the routes call: the server's rules and composed reads, built on :mod:`robobpp.db`.

A route (``server/api``, ``server/site``, ``server/pages.py``) parses the request, calls a service and shapes
the answer: admission (datasets and settings offered, quota, policy URL), access (who sees and cancels a
submission), verification (which entries are re-evaluated), the served forms of submissions and boards.
"""
