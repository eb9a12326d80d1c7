"""ArmWarden: a safety-first MCP server daemon for robot arms.

The model asks; the server decides. Every path to an actuator runs through
`armwarden.guard.Guard`, which enforces the immutable policy loaded at start-up.
"""

__version__ = "0.1.0"

__all__ = ["__version__"]
