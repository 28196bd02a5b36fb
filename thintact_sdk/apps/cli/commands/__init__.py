"""Built-in subcommands. Each module here defines ``register(subparsers)``; the CLI imports
every module of this package, so a new subcommand is a new file and nothing else."""
