"""Problem family module (being written)."""
