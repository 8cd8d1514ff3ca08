"""geovox's version, below every module that writes it into a file or a message."""

__version__ = "0.1.0"

__all__ = ["__version__"]
