"""Dataset system shared by every family: on-disk format, generation, loading, export."""
