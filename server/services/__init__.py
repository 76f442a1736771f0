"""The service layer: what REST routes and the dashboard call. Raises named domain errors."""
