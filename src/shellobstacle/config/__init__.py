"""The configuration: one source of truth for keys and defaults, TOML in and out."""
