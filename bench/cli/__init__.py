"""The ``whiskerbench`` command line: one module per command family (main.py: the parser, the
study commands and error handling; dataset.py, evaluate.py, camera.py, lens.py), how a command
ends beyond its own output (exits.py: bug reports, a closed stdout), shared argument types
(args.py) and the memory and time limits every option is checked against (limits.py). Each
command parses, validates at the boundary and calls an importable function."""
