"""One module per ``nerfkit`` subcommand; see :mod:`nerfkit.cli`."""
