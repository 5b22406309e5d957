"""A user's own system and model for encons, kept outside the encons package (README "Bring your own model")."""
