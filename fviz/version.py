"""fviz's version (its own module: code below the public API reads it without importing ``fviz``'s lazy names)."""

__version__ = "0.1.0"
