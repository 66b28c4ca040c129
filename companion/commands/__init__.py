"""One module per ``merlion`` subcommand (or group member); ``companion.cli`` finds them. See its docstring."""
