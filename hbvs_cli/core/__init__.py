"""The method of Chen et al. (IROS 2003), pure: numpy in, numpy out, no I/O, no printing.
One concept per module (docs/layout.md lists them)."""
