"""The `crank` command line: one subcommand per step of the chain, `crank run` for all of it."""
