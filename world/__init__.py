"""ringtrack: world."""
