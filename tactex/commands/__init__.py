"""Sub-commands of the ``tactex`` CLI, one module each.

A module here defines ``NAME``, ``HELP``, ``register(parser)`` (add its options) and
``run(args) -> int``. :mod:`tactex.cli` discovers them; adding a command is adding a file.
Commands only parse and call :mod:`tactex.tasks` / :mod:`tactex.experiments`.
"""
