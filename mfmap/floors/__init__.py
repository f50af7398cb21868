"""floors stage."""
