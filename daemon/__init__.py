"""ritad: the Rita acquisition daemon (bus, device runners, storage)."""

__version__ = "0.1.0"
