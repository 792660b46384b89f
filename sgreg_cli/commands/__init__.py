"""Subcommands of the sgreg CLI, one module each (NAME, HELP, add_arguments, run); sgreg_cli/main.py
builds the command table from them."""
