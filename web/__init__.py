"""teachrepeat: web."""
