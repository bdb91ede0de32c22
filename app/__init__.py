"""tracklabel's service: FastAPI app, database, jobs and worker, and the CLI."""
