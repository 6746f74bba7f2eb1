"""An example third-party MPM backend for mpmref (docs/checking_your_code.md)."""

__version__ = "0.1.0"
