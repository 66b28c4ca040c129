"""One module per ``merlion`` subcommand (or group member); ``companion.cli`` finds them. See its docstring.

The one place where imports sit inside functions on purpose: every ``merlion`` call (``--help`` included) imports
every module here to build the parser, so a command imports what it runs inside its ``run``. Measured on the
development machine: importing at the top what the commands run adds 9.5 s (torch and open_clip among it) to
``merlion --help``, which takes 1.1 s as it is. At the top of a command module: argparse, json, the standard
library, and nothing of the app that pulls numpy, cv2 or torch.
"""
