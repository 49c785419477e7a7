"""Shipped TOML scenarios, resolved by name (``ringtrack simulate paper-stationary``)."""
