"""HTTP: routes translate requests into service calls and domain errors into status codes."""
