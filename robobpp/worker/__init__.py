"""Episode execution: the unit every executor runs (:func:`robobpp.worker.run.run_claimed`), the local
process pool (:mod:`robobpp.worker.local`); claim/lease/complete live in :mod:`robobpp.db.work`."""
