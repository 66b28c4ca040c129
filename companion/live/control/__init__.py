"""What the surface asks of the live companion: parameters, queries and marks, each handled with an explicit context.

``context.py`` says what a handler may touch; ``params.py`` holds the MERL_* table (name, range, how applied,
how persisted); ``queries.py`` and ``marks.py`` the two uploads. Every change to the summary goes through the
summary keeper's queue (``SummaryKeeper.submit``); see docs/code-layout.md for where a new one goes.
"""
