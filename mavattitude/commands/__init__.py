"""One module per `mavattitude` sub-command, found by the CLI at start-up.

A command module defines ``NAME`` (the sub-command), ``HELP`` (one line for ``mavattitude --help``),
``add_arguments(parser)`` and ``run(args) -> int`` (the exit code). Adding a command is adding a module:
no central list to edit.
"""
