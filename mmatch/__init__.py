"""MMatch: radar-assisted cooperative perception, the method as pure computation.

Nothing in this package opens a socket, starts a thread or touches hardware
(see docs/design.md for the layering).
"""

__version__ = "0.1.0"
