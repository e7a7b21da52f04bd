"""Modules that extend slidewatch the way a user's own code would (named in settings)."""
