"""Models from other projects, made into ordinary dgsdp checkpoints (:mod:`dgsdp.interop.edge`: EDGE's release)."""
