"""One module per `mmatch` sub-command.

Each module defines `HELP: str`, `add_arguments(parser)` and `run(args) -> int`.
Modules stay light at import (heavy libraries are imported inside `run`), so
`mmatch --help` is instant.
"""
