"""The `hypergs` command line: every subcommand's arguments and output (cli.py lists them). The work
is done by the runtime, io/, training/ and bench/."""
