"""Command-line subcommands: thin layers over the pure core."""
