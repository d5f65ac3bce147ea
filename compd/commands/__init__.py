"""One module per `compd` subcommand (see compd.cli)."""
