"""The `cnep` command: `main.main` parses the arguments and runs one subcommand module of this package.

Each subcommand module (`ingest`, `inspect`, `repair`, `extract`, `train`, `replay`, `export`, `run`,
`view`, `evaluate`, `demo`) imports only argparse at module level, so `cnep --help` stays instant.
"""
