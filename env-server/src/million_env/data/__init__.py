"""Data files shipped with the package (instruction sentences)."""
