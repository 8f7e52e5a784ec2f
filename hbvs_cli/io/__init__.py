"""The I/O edge: MCAP files, calibration files, image sources, CSV paths and TOML configs.

Everything that touches bytes lives here; :mod:`hbvs_cli.core` and
:mod:`hbvs_cli.perception` never read or write files."""
