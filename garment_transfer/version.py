"""The version of Garment Transfer (the core, the command line and the extension share it)."""

__version__ = "0.1.0"
