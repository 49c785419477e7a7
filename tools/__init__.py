"""ringtrack: tools."""
