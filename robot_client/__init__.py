"""teachrepeat: robot_client."""
