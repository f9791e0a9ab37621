"""sqpmpc: real-time sparse-QP NMPC for fleets of unicycle robots."""

__all__ = ["__version__"]

__version__ = "0.1.0"
