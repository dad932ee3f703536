"""dgsdp: music- and style-conditioned dance generation (EDGE and DGSDP as one experiment framework)."""

__version__ = "0.1.0"
