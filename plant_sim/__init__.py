"""railhil package."""
