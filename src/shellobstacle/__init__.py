"""shellobstacle: elliptic membrane shells confined to a half-space (Meixner & Piersanti 2024)."""

__version__ = "0.1.0"
