"""ringtrack: agents."""
