"""SQL record of truth: SQLAlchemy models, migrations runner, queries, the work queue (extra ``robobpp[server]``)."""
