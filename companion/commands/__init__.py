"""One module per ``merlion`` subcommand (or group member); ``companion.cli`` finds them. See its docstring.

The one place where imports sit inside functions on purpose: every ``merlion`` call (``--help`` included) imports
every module here to build the parser, so a command imports what it runs inside its ``run``. Measured on the
development machine: importing at the top what the commands run adds 9.5 s (torch and open_clip among it) to
``merlion --help``. At the top of a command module (and of the helpers here, which the parser imports too):
argparse, json, the standard library, and nothing of the app that pulls numpy, cv2, torch, pymavlink or pydantic
(``companion.config``): with those four last ones at the top, ``merlion --help`` took 0.93 s (user CPU 0.74 s),
without them 0.33 s (0.18 s), hyperfine, 20 runs each, interleaved on the shared 2-core machine: 2.9x faster,
4.2x less CPU. ``tests/companion/commands/test_help_speed.py`` checks what ``--help`` loads.
"""
