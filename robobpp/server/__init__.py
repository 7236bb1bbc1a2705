"""The evaluation service: FastAPI app, JSON API, pages, settings (extra ``robobpp[server]``)."""
