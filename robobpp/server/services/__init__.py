"""Server-side services built on the query functions of :mod:`robobpp.db.queries`."""
