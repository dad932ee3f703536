"""EDGE's released model (Stanford-TML/EDGE ``checkpoint.pt``) as a dgsdp checkpoint, read without running code
from the file, and checked against EDGE's own code (``python -m dgsdp.interop.edge import|verify``; docs/edge.md)."""

from dgsdp.errors import UnsafeCheckpointError
from dgsdp.interop.edge.checkpoint import EdgeCheckpoint, EdgeScaler, read_edge_checkpoint
from dgsdp.interop.edge.convert import build_model, import_edge
from dgsdp.interop.edge.weights import EdgeArchitecture, edge_architecture, to_dgsdp

__all__ = [
    "EdgeArchitecture",
    "EdgeCheckpoint",
    "EdgeScaler",
    "UnsafeCheckpointError",
    "build_model",
    "edge_architecture",
    "import_edge",
    "read_edge_checkpoint",
    "to_dgsdp",
]
