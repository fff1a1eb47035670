"""The ``ether-ros`` command. Each subcommand lives in its own module of this package and exposes
``register(subparsers)``; ``main`` discovers them, so adding a command never edits a shared file.
"""
