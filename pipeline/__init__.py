"""The pipeline stages (ingest, extract, train, replay, evaluate, demo) and the `cnep` CLI."""
