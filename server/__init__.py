"""teachrepeat: server."""
