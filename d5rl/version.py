"""d5rl's version (pyproject.toml says the same): importable by every layer, dataset manifests record it."""

__version__ = "0.1.0"
