"""Robot drivers: cameras, motors, depth sensors and clocks behind small Protocols."""
