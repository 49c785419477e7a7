"""ringtrack: bus."""
