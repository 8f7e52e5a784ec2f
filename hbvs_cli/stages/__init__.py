"""One module per subcommand, wiring the core to the I/O edge: parsed options in, data out
where told, messages through the :class:`~hbvs_cli.stages.console.Console` (stderr)."""
