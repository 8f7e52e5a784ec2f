"""One module per subcommand: each wires the core to the I/O edge for one stage.

teach -> fit -> repeat -> report; ``demo`` runs all four. Stages take plain Python values
(already parsed options), write data only where they are told (a file or stdout), and
report progress through the :class:`~hbvs_cli.stages.console.Console` they are given,
which writes to stderr.
"""
