"""What ``hbvs report`` and ``sweep`` show and export: metrics, tables, figures, TUM files.
Submodules are imported by name, so importing this package loads no plotting library."""
