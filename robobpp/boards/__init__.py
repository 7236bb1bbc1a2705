"""Leaderboards: who is ranked, the engine that keeps every board between updates, and their publication.

Data flows one way, engine → store → readers:

* :mod:`~robobpp.boards.records`: what a board and a grid travel as (typed records; their rows are the JSON
  objects a page serves);
* :mod:`~robobpp.boards.ranking`: the one ranking rule (who is ranked, failed or partial), a board and the
  overall grid computed from scratch from plain rows, and the views a page shows of them;
* :mod:`~robobpp.boards.matrix` and :mod:`~robobpp.boards.grid`: one board and one grid kept between
  updates as columns (per-group figures per entry, a few numbers per entry; no samples kept);
* :mod:`~robobpp.boards.engine`: a deployment's boards and grids by track, brought up to date with the
  database (:class:`~robobpp.boards.engine.BoardEngine`), and the from-scratch computation it must equal;
* :mod:`~robobpp.boards.store`: the stored format of a publication (head, chunks, rows, order);
* :mod:`~robobpp.boards.worker`: the board worker, which claims a track, runs the engine and writes the
  publication in the store's format;
* :mod:`~robobpp.boards.reader`: an API process's cache reading publications in that format.
"""
