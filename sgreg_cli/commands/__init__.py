"""Subcommands of the sgreg CLI, one module each (see sgreg_core/cli.py)."""
