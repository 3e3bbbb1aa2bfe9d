"""The ``whiskerbench`` command line: one module per command family; each parses, validates at
the boundary and calls an importable function."""
